"""The one table of planner kinds: each kind is one ``PlannerKind`` entry; the CLI's planner flags, the configuration
union (``PlannerTable.parse_config``) and every planner listing derive from it. Adding a planner: one module in
``letspi/planners/`` plus one entry in ``BUILT_IN_KINDS``.

The table is a value, not a registry: ``planner_table()`` adds to ``BUILT_IN`` the installed kinds of the
``letspi.planners`` entry-point group (``installed_kinds``; broken ones are reported by ``letspi planners``) and
those loaded by import path (``load_kind``, remembered for the process); docs/your-planner.md."""

from __future__ import annotations

import functools
import importlib
import os
import pkgutil
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from difflib import get_close_matches
from enum import Enum
from importlib.metadata import entry_points
from pathlib import Path
from typing import Annotated, Any, Final, Generic, TypeVar, Union

from pydantic import Field, TypeAdapter

from letspi.assembly.build import Builder
from letspi.assembly.resolve import Resolver
from letspi.keyed import Config
from letspi.learned.gnp_model import GnpModel
from letspi.learned.param_mlp import ParamMlp
from letspi.method.choosers import MODEL_CHOOSER, SHUFFLED_CHOOSER, load_teacher, uses_model
from letspi.method.config import DecisionConfig
from letspi.method.thresholds import ReflectionThresholds
from letspi.metrics.registry import Metric
from letspi.physics.neighbours import NeighbourPredictionMode
from letspi.planners import frenet, gnp, idm, mlp, sf, sf_check, sf_opt
from letspi.planners.base import Planner
from letspi.planners.config import GOALS, GoalsConfig, PlannerConfig
from letspi.planners.cv import ConstantVelocityPlanner, CvConfig
from letspi.planners.frenet import FRENET_WEIGHTS, FrenetConfig, FrenetPlanner, FrenetSettings, load_frenet_weights
from letspi.planners.gnp import GnpConfig, GnpPlanner
from letspi.planners.human import HumanConfig, HumanPlanner
from letspi.planners.idm import IdmConfig, IdmPlanner
from letspi.planners.llm import (
    CHOOSER,
    FAST_LLM,
    FAST_OPTIONS,
    FAST_PLANNER_OUTPUTS,
    LLM,
    MEMORY_PLANNER_OPTIONS,
    MEMORY_PLANNER_OUTPUTS,
    SHIELD,
    SHIELD_PRESETS,
    SINGLE_SHOT_OPTIONS,
    TEACHER,
    TOP_K_OPTION,
    ChooserConfig,
    FastPlannerConfig,
    LetsPiFastPlanner,
    LetsPiMemoryPlanner,
    MemoryPlannerConfig,
)
from letspi.planners.mlp import MlpConfig, ParamMlpPlanner
from letspi.planners.options import PlannerOption, PlannerOptions, unique_options
from letspi.planners.outputs import undeclared
from letspi.planners.sf import SfConfig, SocialForcePlanner
from letspi.planners.sf_check import DecisionPlanner, SfCheckConfig
from letspi.planners.sf_opt import SfOptConfig, SocialForceSearchPlanner
from letspi.suggest import did_you_mean

C = TypeVar("C", bound=Config)


class FutureUse(Enum):
    """Whether a kind reads the recorded future (then it is an oracle, not a planner)."""

    NEVER = "no"
    ALWAYS = "always"  # replays the recorded future
    ORACLE_INPUTS = "with oracle inputs"  # --goals oracle or --neighbours ground_truth_oracle


class DemoTable(Enum):
    """The tables of ``letspi demo`` a kind is shown in."""

    BASELINES = "baselines"  # every scenario, no LLM
    HEAD_TO_HEAD = "head-to-head"  # held-back ego vehicles, beside LetsPi


#: (goal configuration or None, neighbour prediction) of a configuration: what can leak the future
PredictionInputs = tuple[GoalsConfig | None, NeighbourPredictionMode]


@dataclass(frozen=True)
class PlannerKind(Generic[C]):
    """One planner kind: ``name`` (the ``--planner`` name, the configuration's ``kind``), a one-line ``description``,
    ``config_class`` (kinds may share one), ``resolve`` (options -> configuration), ``build`` ((builder,
    configuration, label) -> (planner, model load time [s])), the ``options`` ``resolve`` reads; ``future``: whether
    it reads the recorded future (for ``ORACLE_INPUTS``, ``inputs`` gives a configuration's goal source and neighbour
    prediction); ``dual_rate``: a ``DualRatePlanner``; ``demo``: its ``letspi demo`` tables; ``outputs``: the
    per-scenario info it declares (``letspi.planners.outputs.output``; anything else is refused)."""

    name: str
    description: str
    config_class: type[C]
    resolve: Callable[[Resolver], C]
    build: Callable[[Builder, C, str], tuple[Planner, float]]
    options: tuple[PlannerOption[Any], ...] = ()
    future: FutureUse = FutureUse.ORACLE_INPUTS
    inputs: Callable[[C], PredictionInputs] | None = None
    dual_rate: bool = False
    demo: frozenset[DemoTable] = frozenset()
    #: None: undeclared (a planner object given as it is: its info is stored, nothing aggregated)
    outputs: tuple[Metric, ...] | None = ()

    def __post_init__(self) -> None:
        if (self.future is FutureUse.ORACLE_INPUTS) != (self.inputs is not None):
            raise ValueError(f"planner kind {self.name!r}: give inputs exactly when future is ORACLE_INPUTS")
        unique_options([self.options])

    def check_outputs(self, info: Mapping[str, object]) -> None:
        """Refuse per-scenario info the kind does not declare (its ``outputs``)."""
        if self.outputs is None:
            return
        extra = undeclared(info, self.outputs)
        if extra:
            raise PlannerOutputError(
                f"planner kind {self.name!r} reported per-scenario info it does not declare: {', '.join(extra)}; add "
                f"each to its PlannerKind(outputs=...), e.g. letspi.plugin.output({extra[0]!r}, UNIT, DTYPE, DOC)")

    def reads_future(self, config: C) -> bool:
        """Whether a planner built from ``config`` reads the recorded future."""
        if self.inputs is None:
            return self.future is FutureUse.ALWAYS
        goals, neighbours = self.inputs(config)
        return bool((goals is not None and goals.reads_future)
                    or neighbours == NeighbourPredictionMode.GROUND_TRUTH_ORACLE)

    @property
    def uses_llm(self) -> bool:
        """Whether it asks a language model (it reads a model spec)."""
        return LLM in self.options or FAST_LLM in self.options


@dataclass(frozen=True)
class PlannerTable:
    """Planner kinds by name: a value; ``with_kinds`` makes a larger one."""

    kinds: tuple[PlannerKind[Any], ...]
    _by_name: dict[str, PlannerKind[Any]] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        names = [kind.name for kind in self.kinds]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"planner kind(s) {', '.join(dup)} given twice")
        unique_options(kind.options for kind in self.kinds)
        object.__setattr__(self, "_by_name", {kind.name: kind for kind in self.kinds})

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._by_name)

    def outputs(self) -> tuple[Metric, ...]:
        """Every kind's declared per-scenario outputs, each name once (the first declaration)."""
        return tuple({o.name: o for kind in reversed(self.kinds) for o in kind.outputs or ()}.values())

    def with_kinds(self, *kinds: PlannerKind[Any]) -> PlannerTable:
        return PlannerTable((*self.kinds, *kinds))

    def kind(self, name: str) -> PlannerKind[Any]:
        """The entry of ``name`` (``ValueError`` listing the kinds for an unknown one)."""
        try:
            return self._by_name[name]
        except KeyError:
            raise ValueError(unknown_planner(name, self.names)) from None

    def kind_of(self, config: PlannerConfig) -> PlannerKind[Any]:
        """The entry a configuration belongs to (``TypeError`` when its class is not the entry's)."""
        kind = self.kind(config.kind)
        if not isinstance(config, kind.config_class):
            raise TypeError(f"a {type(config).__name__} cannot be planner kind {kind.name!r} "
                            f"(expects {kind.config_class.__name__})")
        return kind

    def reads_future(self, config: PlannerConfig) -> bool:
        """Whether a planner built from ``config`` reads the recorded future (an oracle, not a planner)."""
        return self.kind_of(config).reads_future(config)

    def options(self, names: Iterable[str] | None = None) -> tuple[PlannerOption[Any], ...]:
        """The options of the kinds ``names`` (default: all), each once."""
        kinds = self.kinds if names is None else [self.kind(n) for n in names]
        return unique_options(kind.options for kind in kinds)

    def check(self, options: PlannerOptions) -> None:
        """``ValueError`` naming option values that no kind of the table reads."""
        options.check(self.options())

    def demo(self, table: DemoTable) -> tuple[str, ...]:
        """The kinds ``letspi demo`` shows in ``table``, in table order."""
        return tuple(kind.name for kind in self.kinds if table in kind.demo)

    @functools.cached_property
    def _config_adapter(self) -> TypeAdapter[Any]:
        classes = tuple(dict.fromkeys(kind.config_class for kind in self.kinds))
        # a union built from the table at run time: pydantic reads it, type checkers cannot
        union: Any = Annotated[Union[classes], Field(discriminator="kind")]  # type: ignore[valid-type]  # noqa: UP007
        return TypeAdapter(union)

    def parse_config(self, record: Any) -> PlannerConfig:
        """A planner configuration from its ``record()`` (the discriminated union of the table's classes)."""
        config: PlannerConfig = self._config_adapter.validate_python(record)
        return config

    def planner_help(self) -> str:
        """The CLI's ``--planner`` help: every kind, and how to name one of your own."""
        return (f"Planner KIND ({', '.join(self.names)}; `letspi planners` describes them) or LABEL=KIND for a "
                "second configuration of one kind; repeat for several. A kind of your own: package.module:NAME "
                "(a PlannerKind, imported from the current directory, --planner-path or the Python path) or an "
                f"installed package's kind (entry-point group {ENTRY_POINT_GROUP!r}); see {PLUGIN_DOC}.")


def unknown_planner(name: str, names: Sequence[str]) -> str:
    """The error for a ``--planner`` kind not in the table: the closest names, every name, how to name one's own."""
    return (f"unknown planner {name!r}{did_you_mean(name, names)} (available: {', '.join(names)}; a kind of your own: "
            f"--planner package.module:NAME, see {PLUGIN_DOC})")


# resolution: options -> configuration --------------------------------------------------------------
def _refuse_oracle_neighbours(r: Resolver, kind: str) -> NeighbourPredictionMode:
    if r.neighbours == NeighbourPredictionMode.GROUND_TRUTH_ORACLE:
        raise ValueError(f"{kind} must roll out with predicted neighbours (idm or constant_velocity), "
                         "not the recorded future")
    return r.neighbours


def _resolve_gnp(r: Resolver) -> GnpConfig:
    if r.options.get(GOALS) != "learned":
        raise ValueError("gnp uses its learned goal predictor; --goals applies to the other planners")
    return GnpConfig(neighbours=_refuse_oracle_neighbours(r, "gnp"), goals=r.goals, gnp=r.gnp_weights)


def _resolve_frenet(r: Resolver) -> FrenetConfig:
    path = r.options.get(FRENET_WEIGHTS)
    weights, _ = load_frenet_weights(path)
    return FrenetConfig(neighbours=r.neighbours, goals=r.goals, frenet=FrenetSettings(weights=weights),
                        weights_source="shipped" if path is None else str(path))


def _resolve_mlp(r: Resolver) -> MlpConfig:
    return MlpConfig(neighbours=_refuse_oracle_neighbours(r, "mlp"), goals=r.goals, sf_params=r.sf_params,
                     mlp=r.mlp_weights)


def _resolve_memory(kind: str) -> Callable[[Resolver], MemoryPlannerConfig]:
    def resolve(r: Resolver) -> MemoryPlannerConfig:
        phase = r.memory_phase(max_iterations=0 if kind == "llm" else None)
        return MemoryPlannerConfig(kind=kind, phase=phase, shield=r.options.get(SHIELD))  # type: ignore[arg-type]
    return resolve


def _resolve_chooser(r: Resolver) -> ChooserConfig | None:
    """``--chooser`` (None: the model); the teacher's file fingerprinted."""
    name = r.options.get(CHOOSER)
    if name == MODEL_CHOOSER:
        return None
    if name != "teacher":
        return ChooserConfig(name=name)
    path = r.options.get(TEACHER)
    _, sha = load_teacher(path)
    return ChooserConfig(name=name, teacher_sha256=sha, teacher_path="shipped" if path is None else str(path))


def _shield_presets(r: Resolver, decision: DecisionConfig | None) -> bool | None:
    """None (the shield checks every plan) with ``--shield-presets``, no shield or no decision step; else False."""
    if decision is None or not r.options.get(SHIELD) or r.options.get(SHIELD_PRESETS):
        return None
    return False


def _resolve_fast(kind: str) -> Callable[[Resolver], FastPlannerConfig]:
    def resolve(r: Resolver) -> FastPlannerConfig:
        o = r.options
        chooser = _resolve_chooser(r) if kind == "letspi-fast" else None
        if chooser is not None and not uses_model(chooser.name):  # no model: the choice style's decision step
            llm, decision = None, r.decision("choice", verify=True)
        else:
            llm = r.llm(o.get(FAST_LLM))
            decision = r.decision(llm.prompt_style, verify=True)
            if chooser is not None and llm.prompt_style != "choice":
                raise ValueError("--chooser shuffled asks the model the choice prompt: use --prompt-style choice")
        return FastPlannerConfig(kind=kind, llm=llm, goals=r.goals,  # type: ignore[arg-type]
                                 neighbours=r.neighbours, sf_params=r.sf_params, memory=r.memory_ref(),
                                 top_k=o.get(TOP_K_OPTION), shield=o.get(SHIELD), decision=decision, chooser=chooser,
                                 shield_presets=_shield_presets(r, decision) if kind == "letspi-fast" else None)
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
    shuffle = c.chooser is not None and c.chooser.name == SHUFFLED_CHOOSER
    return LetsPiFastPlanner(phase, neighbour_mode=c.neighbours, shield_params=shield, name=label,
                             shuffle=shuffle, shield_presets=c.shield_presets is None), load_s


def _resolve_sf_check(r: Resolver) -> SfCheckConfig:
    decision = r.decision("paper", always=True)
    if decision is None:
        raise ValueError("sf-check is the decision step without a model: drop --no-decide")
    return SfCheckConfig(neighbours=r.neighbours, goals=r.goals, sf_params=r.sf_params, decision=decision,
                         shield=r.options.get(SHIELD), shield_presets=_shield_presets(r, decision))


def _build_sf_check(b: Builder, c: SfCheckConfig, label: str) -> tuple[Planner, float]:
    params = c.sf_params.params()
    return DecisionPlanner(params=params, decider=c.decision.decider(params, ReflectionThresholds()),
                           goal_predictor=b.goal_predictor(c.goals), neighbour_mode=c.neighbours,
                           shield_params=params if c.shield else None, name=label,
                           shield_presets=c.shield_presets is None), 0.0


def _goals_and_neighbours(c: SfConfig | SfOptConfig | GnpConfig | FrenetConfig | MlpConfig | FastPlannerConfig
                          | SfCheckConfig) -> PredictionInputs:
    return c.goals, c.neighbours


def _phase_inputs(c: MemoryPlannerConfig) -> PredictionInputs:
    return c.phase.goals, c.phase.neighbours


BASELINE = frozenset({DemoTable.BASELINES, DemoTable.HEAD_TO_HEAD})

BUILT_IN_KINDS: tuple[PlannerKind[Any], ...] = (
    PlannerKind("human", "ground-truth replay: the reference row, and the metrics' sanity check",
                HumanConfig, lambda r: HumanConfig(), lambda b, c, label: (HumanPlanner(name=label), 0.0),
                future=FutureUse.ALWAYS, demo=BASELINE),
    PlannerKind("cv", "constant velocity from the t = 0 state", CvConfig, lambda r: CvConfig(),
                lambda b, c, label: (ConstantVelocityPlanner(name=label), 0.0), future=FutureUse.NEVER,
                demo=frozenset({DemoTable.BASELINES})),
    PlannerKind("idm", "IDM car following of the in-lane leader, lateral settle into the lane it heads for",
                IdmConfig, lambda r: IdmConfig(neighbours=r.neighbours),
                lambda b, c, label: (IdmPlanner(neighbour_mode=c.neighbours, name=label), 0.0), idm.OPTIONS,
                inputs=lambda c: (None, c.neighbours), demo=BASELINE),
    PlannerKind("sf", "social force with the fixed parameters of `letspi fit sf`", SfConfig,
                lambda r: SfConfig(neighbours=r.neighbours, goals=r.goals, sf_params=r.sf_params), _build_sf,
                sf.OPTIONS, inputs=_goals_and_neighbours, demo=BASELINE, outputs=sf.OUTPUTS),
    PlannerKind("sf-opt", "per-scenario search over 27 social force candidates checked against predicted neighbours",
                SfOptConfig, lambda r: SfOptConfig(neighbours=r.neighbours, goals=r.goals, sf_params=r.sf_params),
                _build_sf_opt, sf_opt.OPTIONS, inputs=_goals_and_neighbours, demo=BASELINE, outputs=sf_opt.OUTPUTS),
    PlannerKind("sf-check", "the decision step without a model: presets checked against the prediction and the "
                "adverse futures, the defaults unless a check fails (where the risk gate fires), the LLM shield",
                SfCheckConfig, _resolve_sf_check, _build_sf_check, sf_check.OPTIONS, inputs=_goals_and_neighbours,
                demo=frozenset({DemoTable.HEAD_TO_HEAD}), outputs=sf_check.OUTPUTS),
    PlannerKind("gnp", "Goal-based Neural Physics: learned tau and neighbour weights, learned goals", GnpConfig,
                _resolve_gnp, _build_gnp, gnp.OPTIONS, inputs=_goals_and_neighbours, demo=BASELINE,
                outputs=gnp.OUTPUTS),
    PlannerKind("frenet", "Werling-style lattice: quintic/quartic candidates to lanes, speeds and predicted leaders; "
                "the cheapest one clear of the predicted neighbours (weights from `letspi fit frenet`)", FrenetConfig,
                _resolve_frenet, _build_frenet, frenet.OPTIONS, inputs=_goals_and_neighbours, outputs=frenet.OUTPUTS),
    PlannerKind("mlp", "regressor ablation: an MLP maps matching features to the eight LLM answers (needs "
                "--mlp-weights)", MlpConfig, _resolve_mlp, _build_mlp, mlp.OPTIONS, inputs=_goals_and_neighbours,
                outputs=mlp.OUTPUTS),
    PlannerKind("llm", "single-shot LLM: physics-informed prompt, no reflection, no memory", MemoryPlannerConfig,
                _resolve_memory("llm"), _build_memory, SINGLE_SHOT_OPTIONS, inputs=_phase_inputs, dual_rate=True,
                outputs=MEMORY_PLANNER_OUTPUTS),
    PlannerKind("letspi-memory", "LetsPi's memory collection phase as a planner: prompt and reflection",
                MemoryPlannerConfig, _resolve_memory("letspi-memory"), _build_memory, MEMORY_PLANNER_OPTIONS,
                inputs=_phase_inputs, dual_rate=True, demo=frozenset({DemoTable.HEAD_TO_HEAD}),
                outputs=MEMORY_PLANNER_OUTPUTS),
    PlannerKind("letspi-fast", "LetsPi's fast inference phase: top-k retrieved memories in the fast prompt (needs "
                "--memory)", FastPlannerConfig, _resolve_fast("letspi-fast"), _build_fast, FAST_OPTIONS,
                inputs=_goals_and_neighbours, dual_rate=True, demo=frozenset({DemoTable.HEAD_TO_HEAD}),
                outputs=FAST_PLANNER_OUTPUTS),
    PlannerKind("letspi-fs", "the FS ablation: the fast prompt with three static examples (needs --memory)",
                FastPlannerConfig, _resolve_fast("letspi-fs"), _build_fast, FAST_OPTIONS, inputs=_goals_and_neighbours,
                dual_rate=True, outputs=FAST_PLANNER_OUTPUTS),
)
#: the built-in kinds
BUILT_IN = PlannerTable(BUILT_IN_KINDS)


# kinds from outside letspi ------------------------------------------------------------------------
#: the entry-point group through which installed packages add planner kinds
ENTRY_POINT_GROUP: Final = "letspi.planners"
#: where to read how to write one
PLUGIN_DOC: Final = "docs/your-planner.md"


class PlannerOutputError(ValueError):
    """A planner reported per-scenario info its kind does not declare (the message names it and the fix)."""


class PlannerKindError(ValueError):
    """A planner kind from outside letspi that cannot be used (the message names it and why)."""


def _checked(obj: object, where: str, table: PlannerTable) -> PlannerKind[Any]:
    """``obj`` as a kind that can join ``table``: a ``PlannerKind`` whose configuration declares a version."""
    if not isinstance(obj, PlannerKind):
        what = "a class" if isinstance(obj, type) else f"a {type(obj).__name__}"
        raise PlannerKindError(f"{where} is {what}, not a letspi PlannerKind: wrap the planner in one ({PLUGIN_DOC})")
    if obj.name in table.names:
        raise PlannerKindError(f"{where}: planner kind {obj.name!r} exists already")
    if not (isinstance(obj.config_class, type) and issubclass(obj.config_class, Config)):
        raise PlannerKindError(f"{where}: its configuration {obj.config_class!r} is not a letspi.plugin.Config "
                               "subclass (a frozen pydantic model whose fields key its results)")
    declared = obj.config_class.model_fields.get("kind")
    config_kind = declared.default if declared is not None else None
    if config_kind != obj.name:
        raise PlannerKindError(f"{where}: the PlannerKind is named {obj.name!r} but its configuration "
                               f"{obj.config_class.__name__} has kind {config_kind!r}; give both one name "
                               f"(kind: Literal[{obj.name!r}] = {obj.name!r})")
    version = obj.config_class.model_fields.get("version")
    if version is None:
        raise PlannerKindError(f"{where}: its configuration {obj.config_class.__name__} has no 'version' field; "
                               "declare what makes its results differ (a version string enters the result key)")
    prefix = obj.name.replace("-", "_") + "_"
    shared = {o.name: o for o in BUILT_IN.options()}
    foreign = [o.name for o in obj.options if shared.get(o.name) != o and not o.name.startswith(prefix)]
    if foreign:  # its own options carry its name, so that they never clash with a command's flags
        raise PlannerKindError(f"{where}: option(s) {', '.join(foreign)} must start with {prefix!r} (or be "
                               "letspi's own option, e.g. letspi.planners.config.GOALS)")
    try:
        table.with_kinds(obj)
    except ValueError as exc:  # an option name another kind declares differently
        raise PlannerKindError(f"{where}: {exc}") from None
    return obj


@dataclass(frozen=True)
class InstalledKinds:
    """The kinds installed packages offer, where each comes from (name -> "package VERSION"), and one line per entry
    point left out."""

    kinds: tuple[PlannerKind[Any], ...]
    origins: dict[str, str]
    problems: tuple[str, ...]


@functools.cache
def installed_kinds() -> InstalledKinds:
    """The kinds installed packages name in ``ENTRY_POINT_GROUP`` (by entry-point name); read once per process."""
    kinds: list[PlannerKind[Any]] = []
    origins: dict[str, str] = {}
    problems: list[str] = []
    for ep in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        dist = getattr(ep, "dist", None)
        package = f"{dist.name} {dist.version}" if dist is not None else "a package"
        where = f"{ep.value} (entry point {ep.name!r} of {package})"
        try:
            kind = _checked(ep.load(), where, BUILT_IN.with_kinds(*kinds))
        except PlannerKindError as exc:
            problems.append(str(exc))
            continue
        except Exception as exc:  # a broken plug-in must not break letspi: it is reported
            problems.append(f"{where}: {type(exc).__name__}: {exc}")
            continue
        kinds.append(kind)
        origins[kind.name] = package
    return InstalledKinds(tuple(kinds), origins, tuple(problems))


def kind_origin(name: str) -> str:
    """Where a kind of the table comes from: "built in", "package VERSION" or "import path MODULE:NAME"."""
    if name in BUILT_IN.names:
        return "built in"
    path = loaded_from(name)
    return f"import path {path}" if path is not None else installed_kinds().origins.get(name, "unknown")


#: kinds loaded by import path in this process (``load_kind``), by path
_BY_PATH: dict[str, PlannerKind[Any]] = {}


def is_import_path(kind: str) -> bool:
    """Whether a ``--planner`` kind names a kind by import path (``mypkg.mod:NAME``)."""
    return ":" in kind


def add_planner_paths(paths: Iterable[str | Path]) -> None:
    """Put the directories ``paths`` first on the Python path (``--planner-path DIR``)."""
    for path in reversed([Path(p) for p in paths]):
        if not path.is_dir():
            raise PlannerKindError(f"--planner-path {path}: no such directory")
        directory = str(path.resolve())
        if directory not in sys.path:
            sys.path.insert(0, directory)


def _in_working_directory(module_name: str) -> bool:
    top = Path(module_name.partition(".")[0])
    return (top.with_suffix(".py")).is_file() or (top.is_dir() and any(top.iterdir()))


def _import_module(module_name: str, where: str) -> object:
    """``module_name`` imported as ``python -m`` would (the working directory searched too); ``PlannerKindError``
    naming the fixes when it is not found, or the file and line where importing it failed."""
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        missing = exc.name or ""
        if not module_name.startswith(missing):  # the module exists; something it imports does not
            raise PlannerKindError(f"{where}: importing {module_name} failed: {exc} (a module it imports; "
                                   "install it)") from None
        parent = sys.modules.get(missing.rpartition(".")[0])
        if parent is not None:  # the package was found, its module was not
            names = [f"{parent.__name__}.{m.name}" for m in pkgutil.iter_modules(getattr(parent, "__path__", []))]
            close = get_close_matches(missing, names, n=1)
            guess = f"; did you mean {close[0]}?" if close else f" (it has: {', '.join(names) or 'no modules'})"
            raise PlannerKindError(f"{where}: package {parent.__name__} has no module {missing}{guess}") from None
        cwd = os.getcwd()
        if cwd not in sys.path and "" not in sys.path and _in_working_directory(module_name):
            sys.path.insert(0, cwd)
            importlib.invalidate_caches()
            return _import_module(module_name, where)
        raise PlannerKindError(
            f"{where}: cannot import {module_name} ({exc}): run letspi in the directory that holds "
            f"{missing.partition('.')[0]}, or add that directory with --planner-path DIR (Python: "
            "planners(..., planner_path=DIR)), or install its package") from None
    except Exception as exc:  # the user's module fails while it is imported: say where
        line = ""
        tb = exc.__traceback__
        while tb is not None:
            line = f" at {tb.tb_frame.f_code.co_filename}:{tb.tb_lineno}"
            tb = tb.tb_next
        if isinstance(exc, SyntaxError) and exc.filename:
            line = f" at {exc.filename}:{exc.lineno}"
        raise PlannerKindError(f"{where}: importing {module_name} raised {type(exc).__name__}: {exc}{line}") from exc


def load_kind(target: str) -> PlannerKind[Any]:
    """The ``PlannerKind`` at ``target`` (``package.module:NAME``), checked (``PlannerKindError`` saying why not); it
    joins ``planner_table()`` for the rest of the process."""
    if target in _BY_PATH:
        return _BY_PATH[target]
    module_name, _, attribute = target.partition(":")
    where = f"--planner {target}"
    if not module_name or not attribute:
        raise PlannerKindError(f"{where}: an import path is package.module:NAME")
    obj = _import_module(module_name, where)
    for part in attribute.split("."):
        if not hasattr(obj, part):
            kinds = [n for n, v in vars(obj).items() if isinstance(v, PlannerKind)] if hasattr(obj, "__dict__") else []
            close = get_close_matches(part, kinds, n=1)
            guess = f"; did you mean {module_name}:{close[0]}?" if close else (
                f" (its PlannerKinds: {', '.join(kinds)})" if kinds else "")
            raise PlannerKindError(f"{where}: {module_name} has no {attribute!r}{guess}")
        obj = getattr(obj, part)
    table = planner_table()
    same = next((k for k in table.kinds if k is obj), None)  # an installed kind named by its path
    kind = same if same is not None else _checked(obj, where, table)
    _BY_PATH[target] = kind
    return kind


def loaded_from(name: str) -> str | None:
    """The import path a kind of this process was loaded from (None: built in or installed)."""
    return next((path for path, kind in _BY_PATH.items() if kind.name == name), None)


def planner_table(extra: Sequence[PlannerKind[Any]] = ()) -> PlannerTable:
    """Every kind a command offers: built-in, installed, loaded by import path, and ``extra``."""
    kinds: dict[str, PlannerKind[Any]] = {}
    for kind in (*installed_kinds().kinds, *_BY_PATH.values(), *extra):
        kinds.setdefault(kind.name, kind)
    return BUILT_IN.with_kinds(*kinds.values()) if kinds else BUILT_IN
