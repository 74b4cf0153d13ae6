"""Everything a planner or an LLM backend from outside letspi needs, in one import (docs/your-planner.md).

A planner is a ``PlannerKind`` joining through the ``ENTRY_POINT_GROUP`` entry-point group or ``--planner
package.module:KIND``; an LLM backend a ``BackendKind`` in the ``LLM_BACKENDS_GROUP`` group under its prefix.
"""

from letspi.assembly.build import Builder
from letspi.assembly.planner_table import ENTRY_POINT_GROUP, FutureUse, PlannerKind
from letspi.assembly.resolve import Resolver
from letspi.constants import DT_S, N_FUTURE, N_HISTORY, T0_INDEX
from letspi.keyed import Config
from letspi.llm.parse import try_parse_json
from letspi.llm.spec import ENTRY_POINT_GROUP as LLM_BACKENDS_GROUP
from letspi.llm.spec import BackendKind, BackendSpec
from letspi.llm.types import DecodingSettings, LLMBackend, LLMConfigError, LLMResponse, LLMTransportError, Message
from letspi.metrics.registry import Agg
from letspi.planners.base import PlanBatch, Planner
from letspi.planners.options import PlannerOption
from letspi.planners.outputs import output
from letspi.scenario.types import ScenarioBatch

__all__ = [
           "DT_S",
           "ENTRY_POINT_GROUP",
           "LLM_BACKENDS_GROUP",
           "N_FUTURE",
           "N_HISTORY",
           "T0_INDEX",
           "Agg",
           "BackendKind",
           "BackendSpec",
           "Builder",
           "Config",
           "DecodingSettings",
           "FutureUse",
           "LLMBackend",
           "LLMConfigError",
           "LLMResponse",
           "LLMTransportError",
           "Message",
           "PlanBatch",
           "Planner",
           "PlannerKind",
           "PlannerOption",
           "Resolver",
           "ScenarioBatch",
           "output",
           "try_parse_json",
]
