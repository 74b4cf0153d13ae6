"""Planner names → planner objects (a plain function, no import-time registry)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from letspi.planners.base import Planner

BASELINE_PLANNERS: tuple[str, ...] = ("human", "cv", "idm", "sf", "sf-opt")


@dataclass(frozen=True)
class PlannerOptions:
    """Options shared by the planners that need them (CLI flags map onto these)."""

    sf_params_file: Path | None = None
    neighbour_mode: str = "idm"
    extra: dict[str, str] = field(default_factory=dict)


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
    raise ValueError(f"unknown planner {name!r}; available: {', '.join(available_planners())}")
