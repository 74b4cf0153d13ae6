"""What the deciding planners (``letspi-fast``, ``letspi-memory``, ``sf-check``) record, and their options."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from letspi.metrics.registry import Agg, Metric
from letspi.planners.base import PlanningContext
from letspi.planners.options import DECISION_PANEL, PlannerOption, file_option
from letspi.planners.outputs import LANE_FACTOR, LON_FACTOR, output
from letspi.safety.adverse import AdverseSettings, adverse_futures, check_futures
from letspi.scenario.types import ScenarioBatch

DECISION = output("decision", "preset", "str", "the chosen preset, or custom for a model's own numbers")
CONSULTED = output("consulted", "bool", "bool", "the model (or the rule) was asked: the risk gate fired",
                   Agg("consulted_pct", "pct", "share of scenarios where the risk gate asked the model"))
RISK_SCORE = output("risk_score", "1", "float64", "the risk gate's probability that the defaults collide "
                    "(NaN: no gate)")
ADVERSE_FAILED = output("adverse_failed", "futures", "str", "adverse futures the first proposal's plan fails, "
                        "comma-separated")
REFINEMENTS = output("refinements", "n", "float64", "reflection rounds after the first proposal")
REASON = output("reason", "text", "str", "why, in one line: the risk against the gate, what the defaults fail, what "
                "was chosen and its checks")
#: what every deciding planner records (``decision_info``, and the goal factors in force)
DECISION_OUTPUTS: tuple[Metric, ...] = (DECISION, CONSULTED, RISK_SCORE, ADVERSE_FAILED, REFINEMENTS, REASON,
                                        LON_FACTOR, LANE_FACTOR)
DECISION_COLUMNS: tuple[str, ...] = tuple(o.name for o in DECISION_OUTPUTS)

# Options of the decision step (``letspi.method.config.DecisionConfig``) ------------------------------------
DECIDE = PlannerOption[bool | None](
    "decide", bool | None, None,
    "LetsPi's decision step: presets checked against the prediction and the adverse futures, a risk gate "
    "(default: on for the choice prompt style and sf-check)", panel=DECISION_PANEL)
PRESETS = file_option("presets_file", "Presets of the decision step (default: the shipped ones)", flag="--presets",
                      panel=DECISION_PANEL)
ADVERSE = PlannerOption("adverse", bool, True, "Decision step: check plans against the adverse futures too "
                        "(off: against the prediction only)", panel=DECISION_PANEL)
GATE = PlannerOption("gate", bool, True, "Decision step: the risk gate of letspi-fast and sf-check (off: the model "
                     "is asked on every scenario)", panel=DECISION_PANEL)
GATE_THRESHOLD = PlannerOption[float | None](
    "gate_threshold", float | None, None,
    "Decision step: the risk score above which the gate asks the model (default: the risk model's recommended "
    "threshold)", panel=DECISION_PANEL)
RISK_MODEL = file_option("risk_model_file", "Decision step: the gate's risk model (default: the shipped one)",
                         flag="--risk-model", panel=DECISION_PANEL)
VERIFY = PlannerOption("verify", bool, False, "Decision step of letspi-fast: a model's choice that fails more checks "
                       "than another preset is replaced by the rule's choice (default off: the model's answer stands; "
                       "on the held-out critical suites the replacement bought no safety and cost 1.9 points of "
                       "success: docs/decisions.md)",
                       panel=DECISION_PANEL)
KEEP_LANE = PlannerOption("keep_lane", bool, False, "Decision step: the rule, the verification and the shield take "
                          "a preset that changes lane only where every preset keeping the lane fails more checks",
                          panel=DECISION_PANEL)
IDM_FALLBACK = PlannerOption("idm_fallback", bool, False, "Decision step: where no preset, memory or sf alternative "
                             "passes the shield's checks, the shield tries an IDM plan too (behind the in-lane leader, "
                             "keeping the lane) and takes it if it fails less", panel=DECISION_PANEL)
DECISION_OPTIONS: tuple[PlannerOption[Any], ...] = (DECIDE, PRESETS, ADVERSE, GATE, GATE_THRESHOLD, RISK_MODEL, VERIFY,
                                                    KEEP_LANE, IDM_FALLBACK)


def decision_info(option: Sequence[str], consulted: np.ndarray, risk_score: np.ndarray,
                  refinements: np.ndarray, reason: Sequence[str]) -> dict[str, np.ndarray]:
    """The decision columns but ``adverse_failed`` (added where the plans are checked)."""
    return {"decision": np.asarray(option, dtype=object), "consulted": np.asarray(consulted, dtype=bool),
            "risk_score": np.asarray(risk_score, dtype=np.float64),
            "refinements": np.asarray(refinements, dtype=np.float64), "reason": np.asarray(reason, dtype=object)}


def adverse_failed_names(batch: ScenarioBatch, context: PlanningContext, plan_xy_m: np.ndarray,
                         plan_vxy_mps: np.ndarray, settings: AdverseSettings | None) -> np.ndarray:
    """(B,) object: the adverse futures each plan fails, comma-separated ("" none or unchecked)."""
    if settings is None or not settings.futures:
        return np.full(len(batch), "", dtype=object)
    futures = adverse_futures(batch, context.neighbours, settings)
    checks = check_futures(batch, plan_xy_m, plan_vxy_mps, context.neighbours, futures)
    return np.asarray(checks.failed_names(settings), dtype=object)
