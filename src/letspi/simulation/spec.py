"""The one seam between the closed-loop engine and planner construction: workers build their planner from a picklable
``PlannerSpec``, so models load once per worker and nothing unpicklable crosses processes."""

from __future__ import annotations

from dataclasses import dataclass

from letspi.assembly.planner_table import PlannerTable, load_kind, loaded_from, planner_table
from letspi.assembly.planners import BuiltPlanner, resolve_planner
from letspi.assembly.planners import build_planner as assemble_planner
from letspi.planners.base import Planner
from letspi.planners.config import PlannerConfig
from letspi.planners.options import PlannerOptions


@dataclass(frozen=True)
class PlannerSpec:
    """A planner by its configuration (picklable; its key identifies the planner in results) and its label ``name``
    (default: the kind). kind_source: the import path of a kind loaded by path, which a worker loads first; None for
    built-in and installed kinds."""

    config: PlannerConfig
    name: str = ""
    kind_source: str | None = None

    def table(self) -> PlannerTable:
        """The planner table with this planner's kind (one loaded by import path is loaded again here)."""
        if self.kind_source is not None:
            load_kind(self.kind_source)
        return planner_table()

    @classmethod
    def of(cls, kind: str, options: PlannerOptions | None = None, *, name: str = "") -> PlannerSpec:
        """Resolve ``kind`` with ``options`` (files and environment are read here, once)."""
        return cls(resolve_planner(kind, options), name or kind)

    @classmethod
    def of_built(cls, built: BuiltPlanner) -> PlannerSpec:
        """The description of a planner built in this process, for a worker to build its own."""
        return cls(built.config, built.name, loaded_from(built.config.kind))

    def __post_init__(self) -> None:
        if not self.name:
            object.__setattr__(self, "name", self.config.kind)


#: What ``run_closed_loop`` accepts as a planner description: a ``PlannerSpec`` (workers build it) or a
#: ``BuiltPlanner`` (used as is; picklable planners only when it crosses a process boundary).
PlannerSpecLike = PlannerSpec | BuiltPlanner


def build_planner(spec: PlannerSpecLike) -> Planner:
    """The planner a description stands for (built in the process that will use it)."""
    if isinstance(spec, BuiltPlanner):
        return spec.planner
    if isinstance(spec, PlannerSpec):
        return assemble_planner(spec.config, spec.name, table=spec.table()).planner
    raise TypeError(f"planner_spec must be a PlannerSpec or a BuiltPlanner, got {type(spec).__name__}")


def spec_name(spec: PlannerSpecLike) -> str:
    """The planner's name as results should show it (without building a PlannerSpec's planner)."""
    if not isinstance(spec, PlannerSpec | BuiltPlanner):
        raise TypeError(f"planner_spec must be a PlannerSpec or a BuiltPlanner, got {type(spec).__name__}")
    return spec.name


def reads_recorded_future(spec: PlannerSpecLike) -> bool:
    """Whether the planner sees the log's future (shifted to each replan) instead of NaN (from the table)."""
    return spec.reads_future if isinstance(spec, BuiltPlanner) else spec.table().reads_future(spec.config)


def runs_dual_rate(spec: PlannerSpecLike) -> bool:
    """Whether the closed loop runs the planner dual-rate (the LLM planners; from the table)."""
    return spec.dual_rate if isinstance(spec, BuiltPlanner) else spec.table().kind_of(spec.config).dual_rate
