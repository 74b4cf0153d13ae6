"""Planner names → planner objects (a plain function, no import-time registry)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from letspi.physics.goals import GoalPredictor, KinematicGoalPredictor, OracleGoalPredictor
from letspi.planners.base import Planner

BASELINE_PLANNERS: tuple[str, ...] = ("human", "cv", "idm", "sf", "sf-opt", "gnp")
LLM_PLANNERS: tuple[str, ...] = ("llm", "letspi-memory", "letspi-fast", "letspi-fs")
DEFAULT_LLM = "llamacpp:smollm2-135m"
DEFAULT_FAST_LLM = "llamacpp:smollm2-135m"
GOAL_SOURCES: tuple[str, ...] = ("learned", "kinematic", "oracle")


@dataclass(frozen=True)
class PlannerOptions:
    """Options shared by the planners that need them (CLI flags map onto these)."""

    sf_params_file: Path | None = None
    neighbour_mode: str = "idm"
    goals: str = "learned"  # learned (shipped transformer; kinematic if no weights), kinematic, oracle
    llm: str = DEFAULT_LLM  # memory-collection / single-shot model spec
    fast_llm: str = DEFAULT_FAST_LLM  # fast-inference model spec
    memory: Path | None = None  # memory bank (SQLite) for letspi-fast / letspi-fs
    memory_key: str | None = None  # only memories collected under this configuration key (None: all)
    top_k: int = 3
    max_iterations: int = 3  # reflection refinements of letspi-memory (0 = "w/o reflection")
    goal_adjustment: bool = True  # False = "w/o goal adjustment" ablation
    llm_cache: bool = True  # persistent response cache


def available_planners() -> tuple[str, ...]:
    return BASELINE_PLANNERS + LLM_PLANNERS


class _Advisors:
    """One ParamAdvisor per model spec for the planners built together (shares the loaded model)."""

    def __init__(self, use_cache: bool) -> None:
        self.use_cache = use_cache
        self._by_spec: dict[str, Any] = {}

    def get(self, spec: str) -> Any:
        if spec not in self._by_spec:
            self._by_spec[spec] = make_advisor(spec, self.use_cache)
        return self._by_spec[spec]


def make_advisor(spec: str, use_cache: bool = True, sf_params_file: Path | None = None) -> Any:
    """A ParamAdvisor for ``spec`` whose fallback (after bounded retries) is the fitted sf parameters."""
    from letspi.llm.client import ParamAdvisor
    from letspi.llm.schema import fallback_reply_from_params
    from letspi.planners.sf_params import load_sf_params

    fallback = fallback_reply_from_params(load_sf_params(sf_params_file)[0])
    return ParamAdvisor(spec, cache="default" if use_cache else None, fallback_reply=fallback)


def make_planners(names: list[str] | tuple[str, ...], options: PlannerOptions | None = None) -> list[Planner]:
    """Build several planners sharing LLM backends (a model is loaded once)."""
    options = options or PlannerOptions()
    advisors = _Advisors(options.llm_cache)
    return [make_planner(name, options, advisors) for name in names]


def make_planner(name: str, options: PlannerOptions | None = None, advisors: _Advisors | None = None) -> Planner:
    """Build the planner called ``name``; unknown names raise ``ValueError`` listing valid ones.

    Non-default options are appended to the planner's name (``sf@constant_velocity``,
    ``sf@my_fit``), so results of different configurations never share a row or a resume key.
    """
    options = options or PlannerOptions()
    if name in LLM_PLANNERS:
        planner = _make_llm(name, options, advisors or _Advisors(options.llm_cache))
    else:
        planner = _make(name, options)
    suffix = []
    if name in ("idm", "sf", "sf-opt") and options.neighbour_mode != "idm":
        suffix.append(str(options.neighbour_mode))
    if name in ("sf", "sf-opt") and options.sf_params_file is not None:
        suffix.append(Path(options.sf_params_file).stem)
    if name in ("sf", "sf-opt", "gnp", *LLM_PLANNERS) and options.goals != "learned":
        suffix.append(f"{options.goals}-goals")
    if name in ("llm", "letspi-memory") and options.llm != DEFAULT_LLM:
        suffix.append(options.llm)
    if name in ("letspi-fast", "letspi-fs") and options.fast_llm != DEFAULT_FAST_LLM:
        suffix.append(options.fast_llm)
    if name == "letspi-memory" and options.max_iterations != 3:
        suffix.append(f"it{options.max_iterations}")
    if name in ("llm", "letspi-memory") and not options.goal_adjustment:
        suffix.append("no-ga")
    if name == "letspi-fast" and options.top_k != 3:
        suffix.append(f"k{options.top_k}")
    if suffix:
        planner.name = "@".join([planner.name, *suffix])
    return planner


def make_goal_predictor(source: str) -> GoalPredictor:
    """``learned`` (shipped weights, kinematic fallback), ``kinematic`` or ``oracle`` (true endpoint)."""
    if source == "learned":
        from letspi.learned import default_goal_predictor

        return default_goal_predictor()
    if source == "kinematic":
        return KinematicGoalPredictor()
    if source == "oracle":
        return OracleGoalPredictor()
    raise ValueError(f"unknown goal source {source!r}; available: {', '.join(GOAL_SOURCES)}")


def _make_llm(name: str, options: PlannerOptions, advisors: _Advisors) -> Planner:
    from letspi.core.phases import FastPhase, MemoryPhase, Retriever
    from letspi.core.thresholds import ReflectionThresholds
    from letspi.physics.neighbours import NeighbourPredictionMode
    from letspi.planners.llm import LetsPiFastPlanner, LetsPiMemoryPlanner
    from letspi.planners.sf_params import load_sf_params

    sf_params, _ = load_sf_params(options.sf_params_file)
    goals = make_goal_predictor(options.goals)
    mode = NeighbourPredictionMode(options.neighbour_mode)
    if name in ("llm", "letspi-memory"):
        iterations = 0 if name == "llm" else options.max_iterations
        phase = MemoryPhase(advisors.get(options.llm), goals, sf_params.r_col_m,
                            thresholds=ReflectionThresholds(max_iterations=iterations), neighbour_mode=mode,
                            goal_adjustment=options.goal_adjustment)
        return LetsPiMemoryPlanner(phase, name=name)
    if options.memory is None:
        raise ValueError(f"{name} needs a memory bank: --memory FILE (build one with `letspi collect`)")
    from letspi.core.memory import MemoryBank
    from letspi.core.phases import memory_example

    if not Path(options.memory).exists():
        raise FileNotFoundError(f"{options.memory}: no memory bank (build one with `letspi collect`)")
    bank = MemoryBank.open(options.memory, readonly=True)
    advisor = advisors.get(options.fast_llm)
    if name == "letspi-fast":
        fast = FastPhase(advisor, goals, sf_params.r_col_m,
                         Retriever(bank, k=options.top_k, config_key=options.memory_key))
        return LetsPiFastPlanner(fast, neighbour_mode=mode, name=name)
    # letspi-fs: three static examples (the first three validated memories), no retrieval
    static = [memory_example(e) for e in bank.get(bank.features_matrix(config_key=options.memory_key).ids[:3])]
    return LetsPiFastPlanner(FastPhase(advisor, goals, sf_params.r_col_m, None, static_examples=static),
                             neighbour_mode=mode, name=name)


def _make(name: str, options: PlannerOptions) -> Planner:
    if name == "human":
        from letspi.planners.human import HumanPlanner

        return HumanPlanner()
    if name == "cv":
        from letspi.planners.cv import ConstantVelocityPlanner

        return ConstantVelocityPlanner()
    if name == "idm":
        from letspi.physics.neighbours import NeighbourPredictionMode
        from letspi.planners.idm import IdmPlanner

        return IdmPlanner(neighbour_mode=NeighbourPredictionMode(options.neighbour_mode))
    if name in ("sf", "sf-opt"):
        from letspi.physics.neighbours import NeighbourPredictionMode
        from letspi.planners.sf import SocialForcePlanner
        from letspi.planners.sf_opt import SocialForceSearchPlanner
        from letspi.planners.sf_params import load_sf_params

        params, _ = load_sf_params(options.sf_params_file)
        mode = NeighbourPredictionMode(options.neighbour_mode)
        goals = make_goal_predictor(options.goals)
        if name == "sf":
            return SocialForcePlanner(params=params, neighbour_mode=mode, goal_predictor=goals)
        return SocialForceSearchPlanner(params=params, neighbour_mode=mode, goal_predictor=goals)
    if name == "gnp":
        from letspi.physics.neighbours import NeighbourPredictionMode
        from letspi.learned.gnp_model import load_gnp_model
        from letspi.learned.goal_model import default_goal_predictor
        from letspi.planners.gnp import GnpPlanner

        if options.goals != "learned":
            raise ValueError("gnp uses its learned goal predictor; --goals applies to sf and sf-opt only")
        return GnpPlanner(model=load_gnp_model(), goal_predictor=default_goal_predictor(),
                          neighbour_mode=NeighbourPredictionMode(options.neighbour_mode))
    raise ValueError(f"unknown planner {name!r}; available: {', '.join(available_planners())}")
