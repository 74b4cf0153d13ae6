"""Everything a planner from outside letspi needs, in one import (docs/your-planner.md): a ``PlannerKind`` with its
``Config`` (a ``version`` field; every field in its key), ``PlannerOption``s prefixed with the kind's name,
``resolve``, ``build`` and declared ``outputs`` (``output``). It joins through the ``ENTRY_POINT_GROUP`` entry-point
group or ``--planner package.module:KIND``."""

from letspi.assembly.build import Builder
from letspi.assembly.planner_table import ENTRY_POINT_GROUP, FutureUse, PlannerKind
from letspi.assembly.resolve import Resolver
from letspi.constants import DT_S, N_FUTURE, N_HISTORY, T0_INDEX
from letspi.keyed import Config
from letspi.metrics.registry import Agg
from letspi.planners.base import PlanBatch, Planner
from letspi.planners.options import PlannerOption
from letspi.planners.outputs import output
from letspi.scenario.types import ScenarioBatch

__all__ = ["DT_S", "ENTRY_POINT_GROUP", "N_FUTURE", "N_HISTORY", "T0_INDEX", "Agg", "Builder", "Config", "FutureUse",
           "PlanBatch", "Planner", "PlannerKind", "PlannerOption", "Resolver", "ScenarioBatch", "output"]
