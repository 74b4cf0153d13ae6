"""What the deciding planners (``letspi-fast``, ``letspi-memory``, ``sf-check``) record per scenario.

Info columns (``DECISION_COLUMNS``): ``decision`` (the preset, or ``custom``), ``consulted`` (the model or
rule was asked), ``risk_score`` (NaN without a gate), ``adverse_failed`` (the futures the first plan fails,
comma-separated), ``refinements`` (rounds after the first) and ``reason`` (why, in one line).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from letspi.planners.base import PlanningContext
from letspi.safety.adverse import AdverseSettings, adverse_futures, check_futures
from letspi.scenario.types import ScenarioBatch

DECISION_COLUMNS: tuple[str, ...] = ("decision", "consulted", "risk_score", "adverse_failed", "refinements",
                                     "reason")


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
