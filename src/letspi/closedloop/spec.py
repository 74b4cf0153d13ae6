"""The one seam between the closed-loop engine and planner construction.

Workers (processes, Ray actors) build their planner themselves from a picklable description, so
models and caches are loaded once per worker and nothing unpicklable crosses a process boundary.
``build_planner`` is the only function that turns a description into a planner; when the planner
configuration objects and registry land, only this module changes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from letspi.closedloop.config import validate_replan_s
from letspi.physics.neighbours import NeighbourPredictionMode
from letspi.planners.base import Planner
from letspi.planners.factory import PlannerOptions, make_planner

#: Planners (base names) that read the recorded future by design.
FUTURE_READING_PLANNERS: frozenset[str] = frozenset({"human"})


@dataclass(frozen=True)
class PlannerSpec:
    """A planner by name and options (picklable), with its own replanning period.

    Attributes:
        name: a planner name of ``letspi.planners.factory`` (``sf``, ``idm``, ``letspi-fast`` ...).
        options: the shared planner options.
        replan_s: this planner's replanning period [s]; None = the run's ``replan_s``. LLM
            planners call their backend at every replan, so a longer period bounds their cost.
    """

    name: str
    options: PlannerOptions = field(default_factory=PlannerOptions)
    replan_s: float | None = None

    def __post_init__(self) -> None:
        if self.replan_s is not None:
            validate_replan_s(self.replan_s)


#: What ``run_closed_loop`` accepts as a planner description: a ``PlannerSpec``, or a picklable
#: planner object (anything with ``name``, ``batch_size`` and ``plan``), used as is.
PlannerSpecLike = PlannerSpec | Planner


def build_planner(spec: PlannerSpecLike) -> Planner:
    """The planner a description stands for (built in the process that will use it)."""
    if isinstance(spec, PlannerSpec):
        return make_planner(spec.name, spec.options)
    if isinstance(spec, Planner):
        return spec
    raise TypeError(
        f"planner_spec must be a PlannerSpec or a planner object (name, batch_size, plan), got {type(spec).__name__}"
    )


def spec_name(spec: PlannerSpecLike) -> str:
    """The planner's name as results should show it (without building a PlannerSpec's planner)."""
    return spec.name if isinstance(spec, PlannerSpec) else str(spec.name)


def spec_replan_s(spec: PlannerSpecLike) -> float | None:
    """The planner's own replanning period [s], or None."""
    value = spec.replan_s if isinstance(spec, PlannerSpec) else getattr(spec, "replan_s", None)
    return None if value is None else validate_replan_s(float(value))


def reads_recorded_future(spec: PlannerSpecLike) -> bool:
    """Whether the planner reads the recorded future (``human``, oracle goals or neighbours).

    Such planners are given the log's future (shifted to each replanning instant) instead of
    NaN; a planner object can declare it with a truthy ``reads_recorded_future`` attribute.
    """
    if isinstance(spec, PlannerSpec):
        opts = spec.options
        return (
            spec.name.split("@")[0] in FUTURE_READING_PLANNERS
            or opts.goals == "oracle"
            or opts.neighbour_mode == NeighbourPredictionMode.GROUND_TRUTH_ORACLE.value
        )
    declared = getattr(spec, "reads_recorded_future", None)
    if declared is not None:
        return bool(declared)
    return str(spec.name).split("@")[0] in FUTURE_READING_PLANNERS
