"""letspi-gap-keeper: an example planner for letspi, installed as a package of its own.

``KIND`` is what letspi needs: the planner kind, found through the ``letspi.planners`` entry point
of this package (pyproject.toml), or by import path (``--planner letspi_gap_keeper:KIND``).
"""

from __future__ import annotations

from typing import Literal

from letspi.plugin import Agg, Builder, Config, FutureUse, Planner, PlannerKind, PlannerOption, Resolver, output
from letspi_gap_keeper.planner import GapKeeperPlanner

__all__ = ["KIND", "GapKeeperConfig", "GapKeeperPlanner"]

#: its one setting: a CLI flag (--gap-keeper-time-gap-s) and a keyword of letspi.api.planners
TIME_GAP = PlannerOption("gap_keeper_time_gap_s", float, 1.5, "time gap the gap keeper keeps to the vehicle ahead",
                         unit="s")


class GapKeeperConfig(Config):
    """Everything that changes the gap keeper's plans; every field enters its result key."""

    kind: Literal["gap-keeper"] = "gap-keeper"
    #: bump it whenever a change to the planner changes its plans: results of another version are refused
    version: str = "1"
    time_gap_s: float = 1.5


def resolve(r: Resolver) -> GapKeeperConfig:
    """The user's options -> the configuration (check them here: one clear error, before anything runs)."""
    time_gap_s = float(r.options.get(TIME_GAP))
    if not 0.3 <= time_gap_s <= 5.0:
        raise ValueError(f"--gap-keeper-time-gap-s must be within 0.3-5 s, got {time_gap_s:g}")
    return GapKeeperConfig(time_gap_s=time_gap_s)


def build(b: Builder, c: GapKeeperConfig, label: str) -> tuple[Planner, float]:
    """The configuration -> the planner, and the seconds its model took to load (none here)."""
    return GapKeeperPlanner(time_gap_s=c.time_gap_s, name=label), 0.0


#: what it reports per scenario beside the plan (stored as the column info_gap_keeper_leader); its share of
#: windows becomes the metrics.json key gap_keeper_leader_pct
OUTPUTS = (output("gap_keeper_leader", "bool", "bool", "a leader was within reach in the ego lane",
                  Agg("gap_keeper_leader_pct", "pct", "share of windows with a leader to keep the gap to")),)

KIND = PlannerKind("gap-keeper", "keeps its lane and a time gap to the vehicle ahead (the example plug-in "
                   "package, examples/letspi-gap-keeper)", GapKeeperConfig, resolve, build, options=(TIME_GAP,),
                   future=FutureUse.NEVER, outputs=OUTPUTS)
