"""Everything a planner from outside letspi needs, in one import (docs/your-planner.md).

A planner kind is plain data, a ``PlannerKind``: a name and a one-line description, a configuration
class (a ``Config`` subclass with a ``kind`` literal, a ``version`` field and every setting that
changes its plans: all of them enter its result key), the ``PlannerOption``s it reads (named with
the kind's name as prefix), ``resolve`` (options -> configuration, through a ``Resolver``) and
``build`` (configuration -> planner and model load time, through a ``Builder``). A planner has a
``name``, a ``batch_size``, ``reads_future = False`` and ``plan(ScenarioBatch) -> PlanBatch``; it
sees the history only (``T0_INDEX`` is t = 0) and plans ``N_FUTURE`` steps of ``DT_S``.

An installed package offers its kind in the ``ENTRY_POINT_GROUP`` entry-point group::

    [project.entry-points."letspi.planners"]
    gap-keeper = "letspi_gap_keeper:KIND"

and ``letspi planners`` lists it; ``--planner package.module:KIND`` loads one without installing.
"""

from letspi.assembly.build import Builder
from letspi.assembly.planner_table import ENTRY_POINT_GROUP, FutureUse, PlannerKind
from letspi.assembly.resolve import Resolver
from letspi.constants import DT_S, N_FUTURE, N_HISTORY, T0_INDEX
from letspi.keyed import Config
from letspi.planners.base import PlanBatch, Planner
from letspi.planners.options import PlannerOption
from letspi.scenario.types import ScenarioBatch

__all__ = ["DT_S", "ENTRY_POINT_GROUP", "N_FUTURE", "N_HISTORY", "T0_INDEX", "Builder", "Config", "FutureUse",
           "PlanBatch", "Planner", "PlannerKind", "PlannerOption", "Resolver", "ScenarioBatch"]
