"""``closed-loop-hybrid``: which log-replayed neighbours the ego's actions now reach (``HandoverConfig``'s
rule, vectorised over scenarios and neighbour slots), and the hybrid settings that enter keys."""

from __future__ import annotations

import hashlib
from dataclasses import asdict
from typing import Any

import numpy as np

from letspi.scenario.queries import OFF_ROAD, lane_index_of
from letspi.simulation.config import ClosedLoopConfig, HandoverConfig


def within_reach(ego_xy_m: np.ndarray, ego_length_m: np.ndarray, ego_width_m: np.ndarray, nbr_xy_m: np.ndarray,
                 nbr_length_m: np.ndarray, marking_y_m: np.ndarray, config: HandoverConfig) -> np.ndarray:
    """(K, N) bool: neighbours behind the ego in a lane its box covers, or ``config.lanes`` lanes beside those.
    ego_xy_m: (K, 2) centres; ego_length_m, ego_width_m: (K,); nbr_xy_m: (K, N, 2) (NaN = absent: never within
    reach); nbr_length_m: (K, N); marking_y_m: (K, M) ascending, NaN padded. The ego covers the lanes its box
    overlaps (the edge lane when beyond an edge); a neighbour is in the lane of its centre (off the road: none)."""
    ego_xy = np.asarray(ego_xy_m, dtype=np.float64)
    nbr_xy = np.asarray(nbr_xy_m, dtype=np.float64)
    marks = np.asarray(marking_y_m, dtype=np.float64)
    inner = 1e-6  # a box edge exactly on a marking does not cover the lane beyond it
    lo_y = np.nanmin(marks, axis=1) + inner
    hi_y = np.nanmax(marks, axis=1) - inner
    half_w = 0.5 * np.asarray(ego_width_m, dtype=np.float64)
    ego_lo = lane_index_of(marks, np.clip(ego_xy[:, 1] - half_w + inner, lo_y, hi_y))  # (K,)
    ego_hi = lane_index_of(marks, np.clip(ego_xy[:, 1] + half_w - inner, lo_y, hi_y))
    nbr_lane = lane_index_of(marks, nbr_xy[..., 1])  # (K, N)
    near = (nbr_lane != OFF_ROAD) & np.isfinite(ego_xy[:, 1:2])
    near &= (nbr_lane >= ego_lo[:, None] - config.lanes) & (nbr_lane <= ego_hi[:, None] + config.lanes)
    nbr_front = nbr_xy[..., 0] + 0.5 * np.asarray(nbr_length_m, dtype=np.float64)
    ego_rear = ego_xy[:, 0] - 0.5 * np.asarray(ego_length_m, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        behind = nbr_front <= ego_rear[:, None] - config.behind_m
    return np.asarray(near & behind)


def scripted_summary(scripted_nbr: np.ndarray | None) -> dict[str, Any]:
    """What of a scripted-neighbour mask (B, N) enters keys: scripted slots ``n`` and a ``digest`` ("none": none)."""
    if scripted_nbr is None or not np.any(scripted_nbr):
        return {"n": 0, "digest": "none"}
    mask = np.ascontiguousarray(np.asarray(scripted_nbr, dtype=bool))
    digest = hashlib.blake2b(f"{mask.shape}".encode() + mask.tobytes(), digest_size=8).hexdigest()
    return {"n": int(mask.sum()), "digest": digest}


def hybrid_settings(config: ClosedLoopConfig, scripted_nbr: np.ndarray | None) -> dict[str, Any]:
    """What of ``closed-loop-hybrid`` changes answers besides the driver model: hand-over rule, scripted neighbours."""
    return {"handover": asdict(config.handover), "scripted": scripted_summary(scripted_nbr)}
