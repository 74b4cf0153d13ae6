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
    if suffix:
        planner.name = "@".join([planner.name, *suffix])
    return planner


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
        if name == "sf":
            return SocialForcePlanner(params=params, neighbour_mode=mode)
        return SocialForceSearchPlanner(params=params, neighbour_mode=mode)
    raise ValueError(f"unknown planner {name!r}; available: {', '.join(available_planners())}")
