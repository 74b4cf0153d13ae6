"""Goal-prediction metrics (NumPy): minFDE@K and miss rate against the recorded ego position at the horizon."""

from __future__ import annotations

import numpy as np

from letspi.constants import N_FUTURE, T0_INDEX
from letspi.physics.goals import GoalPrediction
from letspi.scenario.types import ScenarioBatch

MISS_THRESHOLD_M = 2.0


def goal_truth(batch: ScenarioBatch, n_steps: int = N_FUTURE) -> np.ndarray:
    """The recorded ego position at the horizon, (B, 2) [m] (evaluation / training target only)."""
    return batch.ego_xy_m[:, T0_INDEX + n_steps].astype(np.float64)


def goal_metrics(prediction: GoalPrediction, truth_xy_m: np.ndarray, ks: tuple[int, ...] = (1, 5),
                 miss_threshold_m: float = MISS_THRESHOLD_M) -> dict[str, float]:
    """Per k: ``min_fde_at_{k}_m`` (mean best top-k goal error [m]) and ``miss_rate_at_{k}`` (share whose best
    error exceeds ``miss_threshold_m``); with fewer than k goals, all are used."""
    g = prediction.goals_xy_m
    err = np.linalg.norm(g - np.asarray(truth_xy_m, dtype=np.float64)[:, None, :], axis=-1)  # (B, K)
    ok = np.isfinite(err).all(axis=1)
    out: dict[str, float] = {"n": float(ok.sum())}
    for k in ks:
        best = err[ok, : min(k, g.shape[1])].min(axis=1)
        out[f"min_fde_at_{k}_m"] = float(best.mean()) if len(best) else float("nan")
        out[f"miss_rate_at_{k}"] = float((best > miss_threshold_m).mean()) if len(best) else float("nan")
    return out
