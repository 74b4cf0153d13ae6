"""The one table of planner kinds: each kind is one entry, everything else is derived from it.

An entry names a kind, says in one line what it is, and gives its configuration class (defined
beside the planner, in its module under ``letspi.planners``), how ``PlannerOptions`` resolve into
that configuration (``Resolver``: files and environment read once, fingerprinted) and how the
configuration is built into a planner (``Builder``: models shared, load time reported). From the
table come ``PLANNER_KINDS``, the discriminated configuration union (``parse_planner_config``),
``Resolver.planner``, ``Builder.planner``, the CLI's ``--planner`` help, the error for an unknown
name and ``letspi planners``.

Adding a planner: write ``letspi/planners/<name>.py`` with the planner and its ``Config`` subclass
(a ``kind: Literal["<name>"]`` field and everything that changes its answers), then add one
``PlannerKind`` to ``PLANNER_TABLE`` below.

``Resolver`` and ``Builder`` call into this table and the table's functions take them as arguments,
so they are imported for type checking only (``resolve`` and ``build`` import this module).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Generic, TypeVar, Union

from pydantic import Field, TypeAdapter

from letspi.learned.gnp_model import GnpModel
from letspi.learned.param_mlp import ParamMlp
from letspi.method.thresholds import ReflectionThresholds
from letspi.physics.neighbours import NeighbourPredictionMode
from letspi.planners.base import Planner
from letspi.planners.config import Config, GoalsConfig, PlannerConfig
from letspi.planners.cv import ConstantVelocityPlanner, CvConfig
from letspi.planners.frenet import FrenetConfig, FrenetPlanner, FrenetSettings, load_frenet_weights
from letspi.planners.gnp import GnpConfig, GnpPlanner
from letspi.planners.human import HumanConfig, HumanPlanner
from letspi.planners.idm import IdmConfig, IdmPlanner
from letspi.planners.llm import FastPlannerConfig, LetsPiFastPlanner, LetsPiMemoryPlanner, MemoryPlannerConfig
from letspi.planners.mlp import MlpConfig, ParamMlpPlanner
from letspi.planners.sf import SfConfig, SocialForcePlanner
from letspi.planners.sf_check import DecisionPlanner, SfCheckConfig
from letspi.planners.sf_opt import SfOptConfig, SocialForceSearchPlanner

if TYPE_CHECKING:  # both import this module at run time
    from letspi.assembly.build import Builder
    from letspi.assembly.resolve import Resolver

C = TypeVar("C", bound=Config)


class FutureUse(Enum):
    """Whether a kind reads the recorded future (then it is an oracle, not a planner)."""

    NEVER = "no"
    ALWAYS = "always"  # replays the recorded future
    ORACLE_INPUTS = "with oracle inputs"  # --goals oracle or --neighbour-mode ground_truth_oracle


#: (goal configuration or None, neighbour prediction) of a configuration: what can leak the future
PredictionInputs = tuple[GoalsConfig | None, NeighbourPredictionMode]


@dataclass(frozen=True)
class PlannerKind(Generic[C]):
    """One planner kind.

    name: the ``--planner`` name (the configuration's ``kind``). description: one line for listings.
    config_class: its configuration (several kinds may share one, told apart by ``kind``).
    resolve: options -> configuration. build: (builder, configuration, label) -> (planner, model
    load time [s]). future: whether it reads the recorded future; for ``ORACLE_INPUTS``,
    ``inputs`` says which goal source and neighbour prediction a configuration uses.
    """

    name: str
    description: str
    config_class: type[C]
    resolve: Callable[[Resolver], C]
    build: Callable[[Builder, C, str], tuple[Planner, float]]
    future: FutureUse = FutureUse.ORACLE_INPUTS
    inputs: Callable[[C], PredictionInputs] | None = None

    def __post_init__(self) -> None:
        if (self.future is FutureUse.ORACLE_INPUTS) != (self.inputs is not None):
            raise ValueError(f"planner kind {self.name!r}: give inputs exactly when future is ORACLE_INPUTS")

    def reads_future(self, config: C) -> bool:
        """Whether a planner built from ``config`` reads the recorded future."""
        if self.inputs is None:
            return self.future is FutureUse.ALWAYS
        goals, neighbours = self.inputs(config)
        return bool((goals is not None and goals.reads_future)
                    or neighbours == NeighbourPredictionMode.GROUND_TRUTH_ORACLE)


# resolution: options -> configuration --------------------------------------------------------------
def _resolve_gnp(r: Resolver) -> GnpConfig:
    if r.options.goals != "learned":
        raise ValueError("gnp uses its learned goal predictor; --goals applies to the other planners")
    if r.neighbours == NeighbourPredictionMode.GROUND_TRUTH_ORACLE:
        raise ValueError("gnp must roll out with predicted neighbours (idm or constant_velocity), "
                         "not the recorded future")
    return GnpConfig(neighbours=r.neighbours, goals=r.goals, gnp=r.gnp_weights)


def _resolve_frenet(r: Resolver) -> FrenetConfig:
    path = r.options.frenet_weights_file
    weights, _ = load_frenet_weights(path)
    return FrenetConfig(neighbours=r.neighbours, goals=r.goals, frenet=FrenetSettings(weights=weights),
                        weights_source="shipped" if path is None else str(path))


def _resolve_mlp(r: Resolver) -> MlpConfig:
    if r.neighbours == NeighbourPredictionMode.GROUND_TRUTH_ORACLE:
        raise ValueError("mlp must roll out with predicted neighbours (idm or constant_velocity)")
    return MlpConfig(neighbours=r.neighbours, goals=r.goals, sf_params=r.sf_params, mlp=r.mlp_weights)


def _resolve_memory(kind: str) -> Callable[[Resolver], MemoryPlannerConfig]:
    def resolve(r: Resolver) -> MemoryPlannerConfig:
        phase = r.memory_phase(max_iterations=0 if kind == "llm" else None)
        return MemoryPlannerConfig(kind=kind, phase=phase, shield=r.options.shield)  # type: ignore[arg-type]
    return resolve


def _resolve_fast(kind: str) -> Callable[[Resolver], FastPlannerConfig]:
    def resolve(r: Resolver) -> FastPlannerConfig:
        o = r.options
        llm = r.llm(o.fast_llm)
        return FastPlannerConfig(kind=kind, llm=llm, goals=r.goals,  # type: ignore[arg-type]
                                 neighbours=r.neighbours, sf_params=r.sf_params, memory=r.memory_ref(),
                                 top_k=o.top_k, shield=o.shield, decision=r.decision(llm.prompt_style))
    return resolve


# building: configuration -> planner -----------------------------------------------------------------
def _build_sf(b: Builder, c: SfConfig, label: str) -> tuple[Planner, float]:
    return SocialForcePlanner(params=c.sf_params.params(), goal_predictor=b.goal_predictor(c.goals),
                              neighbour_mode=c.neighbours, name=label), 0.0


def _build_sf_opt(b: Builder, c: SfOptConfig, label: str) -> tuple[Planner, float]:
    return SocialForceSearchPlanner(params=c.sf_params.params(), space=c.search,
                                    goal_predictor=b.goal_predictor(c.goals), neighbour_mode=c.neighbours,
                                    name=label), 0.0


def _build_gnp(b: Builder, c: GnpConfig, label: str) -> tuple[Planner, float]:
    return GnpPlanner(model=GnpModel.from_dir(c.gnp.weights_dir), goal_predictor=b.goal_predictor(c.goals),
                      neighbour_mode=c.neighbours, name=label), 0.0


def _build_frenet(b: Builder, c: FrenetConfig, label: str) -> tuple[Planner, float]:
    return FrenetPlanner(settings=c.frenet, goal_predictor=b.goal_predictor(c.goals), neighbour_mode=c.neighbours,
                         name=label), 0.0


def _build_mlp(b: Builder, c: MlpConfig, label: str) -> tuple[Planner, float]:
    return ParamMlpPlanner(model=ParamMlp.from_dir(Path(c.mlp.weights_dir)), goal_predictor=b.goal_predictor(c.goals),
                           r_col_m=float(c.sf_params.values["r_col_m"]), neighbour_mode=c.neighbours,
                           name=label), 0.0


def _build_memory(b: Builder, c: MemoryPlannerConfig, label: str) -> tuple[Planner, float]:
    phase, load_s = b.memory_phase(c.phase)
    shield = c.phase.sf_params.params() if c.shield else None
    return LetsPiMemoryPlanner(phase, name=label, shield_params=shield), load_s


def _build_fast(b: Builder, c: FastPlannerConfig, label: str) -> tuple[Planner, float]:
    phase, load_s = b.fast_phase(c)
    shield = c.sf_params.params() if c.shield else None
    return LetsPiFastPlanner(phase, neighbour_mode=c.neighbours, shield_params=shield, name=label), load_s


def _resolve_sf_check(r: Resolver) -> SfCheckConfig:
    decision = r.decision("paper", always=True)
    assert decision is not None
    return SfCheckConfig(neighbours=r.neighbours, goals=r.goals, sf_params=r.sf_params, decision=decision,
                         shield=r.options.shield)


def _build_sf_check(b: Builder, c: SfCheckConfig, label: str) -> tuple[Planner, float]:
    params = c.sf_params.params()
    return DecisionPlanner(params=params, decider=c.decision.decider(params, ReflectionThresholds()),
                           goal_predictor=b.goal_predictor(c.goals), neighbour_mode=c.neighbours,
                           shield_params=params if c.shield else None, name=label), 0.0


def _goals_and_neighbours(c: SfConfig | SfOptConfig | GnpConfig | FrenetConfig | MlpConfig | FastPlannerConfig
                          | SfCheckConfig) -> PredictionInputs:
    return c.goals, c.neighbours


PLANNER_TABLE: tuple[PlannerKind[Any], ...] = (
    PlannerKind("human", "ground-truth replay: the reference row, and the metrics' sanity check",
                HumanConfig, lambda r: HumanConfig(), lambda b, c, label: (HumanPlanner(name=label), 0.0),
                future=FutureUse.ALWAYS),
    PlannerKind("cv", "constant velocity from the t = 0 state", CvConfig, lambda r: CvConfig(),
                lambda b, c, label: (ConstantVelocityPlanner(name=label), 0.0), future=FutureUse.NEVER),
    PlannerKind("idm", "IDM car following of the in-lane leader, lateral settle into the lane it heads for",
                IdmConfig, lambda r: IdmConfig(neighbours=r.neighbours),
                lambda b, c, label: (IdmPlanner(neighbour_mode=c.neighbours, name=label), 0.0),
                inputs=lambda c: (None, c.neighbours)),
    PlannerKind("sf", "social force with the fixed parameters of `letspi fit sf`", SfConfig,
                lambda r: SfConfig(neighbours=r.neighbours, goals=r.goals, sf_params=r.sf_params), _build_sf,
                inputs=_goals_and_neighbours),
    PlannerKind("sf-opt", "per-scenario search over 27 social force candidates checked against predicted neighbours",
                SfOptConfig, lambda r: SfOptConfig(neighbours=r.neighbours, goals=r.goals, sf_params=r.sf_params),
                _build_sf_opt, inputs=_goals_and_neighbours),
    PlannerKind("sf-check", "the decision step without a model: presets checked against the prediction and the "
                "adverse futures, the defaults unless a check fails (where the risk gate fires), the LLM shield",
                SfCheckConfig, _resolve_sf_check, _build_sf_check, inputs=_goals_and_neighbours),
    PlannerKind("gnp", "Goal-based Neural Physics: learned tau and neighbour weights, learned goals", GnpConfig,
                _resolve_gnp, _build_gnp, inputs=_goals_and_neighbours),
    PlannerKind("frenet", "Werling-style lattice: quintic/quartic candidates to lanes, speeds and predicted leaders; "
                "the cheapest one clear of the predicted neighbours (weights from `letspi fit frenet`)", FrenetConfig,
                _resolve_frenet, _build_frenet, inputs=_goals_and_neighbours),
    PlannerKind("mlp", "regressor ablation: an MLP maps matching features to the eight LLM answers (needs "
                "--mlp-weights)", MlpConfig, _resolve_mlp, _build_mlp, inputs=_goals_and_neighbours),
    PlannerKind("llm", "single-shot LLM: physics-informed prompt, no reflection, no memory", MemoryPlannerConfig,
                _resolve_memory("llm"), _build_memory, inputs=lambda c: (c.phase.goals, c.phase.neighbours)),
    PlannerKind("letspi-memory", "LetsPi's memory collection phase as a planner: prompt and reflection",
                MemoryPlannerConfig, _resolve_memory("letspi-memory"), _build_memory,
                inputs=lambda c: (c.phase.goals, c.phase.neighbours)),
    PlannerKind("letspi-fast", "LetsPi's fast inference phase: top-k retrieved memories in the fast prompt (needs "
                "--memory)", FastPlannerConfig, _resolve_fast("letspi-fast"), _build_fast,
                inputs=_goals_and_neighbours),
    PlannerKind("letspi-fs", "the FS ablation: the fast prompt with three static examples (needs --memory)",
                FastPlannerConfig, _resolve_fast("letspi-fs"), _build_fast, inputs=_goals_and_neighbours),
)

PLANNER_KINDS: tuple[str, ...] = tuple(kind.name for kind in PLANNER_TABLE)
_BY_NAME: dict[str, PlannerKind[Any]] = {kind.name: kind for kind in PLANNER_TABLE}


def planner_kind(name: str) -> PlannerKind[Any]:
    """The entry of ``name`` (``ValueError`` listing the kinds for an unknown one)."""
    try:
        return _BY_NAME[name]
    except KeyError:
        raise ValueError(f"unknown planner {name!r}; available: {', '.join(PLANNER_KINDS)}") from None


def kind_of(config: PlannerConfig) -> PlannerKind[Any]:
    """The entry a configuration belongs to (``TypeError`` when its class is not the entry's)."""
    kind = planner_kind(config.kind)
    if not isinstance(config, kind.config_class):
        raise TypeError(f"a {type(config).__name__} cannot be planner kind {kind.name!r} "
                        f"(expects {kind.config_class.__name__})")
    return kind


def reads_future(config: PlannerConfig) -> bool:
    """Whether a planner built from ``config`` reads the recorded future (an oracle, not a planner):
    ``human`` replays it; oracle goals or oracle neighbour prediction leak it."""
    return kind_of(config).reads_future(config)


@cache
def _config_adapter() -> TypeAdapter[Any]:
    classes = tuple(dict.fromkeys(kind.config_class for kind in PLANNER_TABLE))
    # a union built from the table at run time: pydantic reads it, type checkers cannot
    union: Any = Annotated[Union[classes], Field(discriminator="kind")]  # type: ignore[valid-type]  # noqa: UP007
    return TypeAdapter(union)


def parse_planner_config(record: Any) -> PlannerConfig:
    """A planner configuration from its ``record()`` (the discriminated union of the table's classes)."""
    config: PlannerConfig = _config_adapter().validate_python(record)
    return config


def planner_help() -> str:
    """The CLI's ``--planner`` help: every kind, from the table."""
    return (f"Planner KIND ({', '.join(PLANNER_KINDS)}; `letspi planners` describes them) or LABEL=KIND for a "
            "second configuration of one kind; repeat for several.")
