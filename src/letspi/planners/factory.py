"""Planner names → planner objects (a plain function, no import-time registry)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from letspi.physics.goals import GoalPredictor, KinematicGoalPredictor, OracleGoalPredictor
from letspi.planners.base import Planner

BASELINE_PLANNERS: tuple[str, ...] = ("human", "cv", "idm", "sf", "sf-opt", "gnp")
GOAL_SOURCES: tuple[str, ...] = ("learned", "kinematic", "oracle")


@dataclass(frozen=True)
class PlannerOptions:
    """Options shared by the planners that need them (CLI flags map onto these)."""

    sf_params_file: Path | None = None
    neighbour_mode: str = "idm"
    goals: str = "learned"  # learned (shipped transformer; kinematic if no weights), kinematic, oracle


def available_planners() -> tuple[str, ...]:
    return BASELINE_PLANNERS


def make_planner(name: str, options: PlannerOptions | None = None) -> Planner:
    """Build the planner called ``name``; unknown names raise ``ValueError`` listing valid ones.

    Non-default options are appended to the planner's name (``sf@constant_velocity``,
    ``sf@my_fit``), so results of different configurations never share a row or a resume key.
    """
    options = options or PlannerOptions()
    planner = _make(name, options)
    suffix = []
    if name in ("idm", "sf", "sf-opt") and options.neighbour_mode != "idm":
        suffix.append(str(options.neighbour_mode))
    if name in ("sf", "sf-opt") and options.sf_params_file is not None:
        suffix.append(Path(options.sf_params_file).stem)
    if name in ("sf", "sf-opt", "gnp") and options.goals != "learned":
        suffix.append(f"{options.goals}-goals")
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
        from letspi.learned.gnp_model import GnpPlanner

        if options.goals != "learned":
            raise ValueError("gnp uses its learned goal predictor; --goals applies to sf and sf-opt only")
        return GnpPlanner.from_dir(neighbour_mode=options.neighbour_mode)
    raise ValueError(f"unknown planner {name!r}; available: {', '.join(available_planners())}")
