"""Planner names → planner objects (a plain function, no import-time registry)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from letspi.planners.base import Planner

BASELINE_PLANNERS: tuple[str, ...] = ("human", "cv", "idm", "sf", "sf-opt")


@dataclass(frozen=True)
class PlannerOptions:
    """Options shared by the planners that need them (CLI flags map onto these)."""

    sf_params_file: Path | None = None
    neighbour_mode: str = "idm"


def available_planners() -> tuple[str, ...]:
    return BASELINE_PLANNERS


def make_planner(name: str, options: PlannerOptions | None = None) -> Planner:
    """Build the planner called ``name``; unknown names raise ``ValueError`` listing valid ones."""
    options = options or PlannerOptions()
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
        if name == "sf":
            return SocialForcePlanner(params=params, neighbour_mode=mode)
        return SocialForceSearchPlanner(params=params, neighbour_mode=mode)
    raise ValueError(f"unknown planner {name!r}; available: {', '.join(available_planners())}")
