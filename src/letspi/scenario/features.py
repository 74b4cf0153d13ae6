"""Scenario features for memory matching (paper §III-E), from what is observable at t = 0.

``scenario_features`` (B, 6), columns ``FEATURE_NAMES``: visible neighbours; ego speed; ``lane_change`` (1.0 when
the ego changed lane in its history or its lateral speed exceeds ``LANE_CHANGE_LAT_SPEED_MPS``); min and mean
centre distance to the visible neighbours; their mean speed. Always finite (the memory bank refuses others):
without a visible neighbour the distances are ``NEIGHBOUR_RADIUS_M`` and the speed the ego's; a neighbour
with non-finite values at t = 0 is not visible; a non-finite ego speed counts as 0.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from letspi.constants import NEIGHBOUR_RADIUS_M, T0_INDEX
from letspi.scenario.types import ScenarioBatch

FEATURE_NAMES: Final[tuple[str, ...]] = (
    "n_vehicles",
    "ego_speed_mps",
    "lane_change",
    "min_dist_m",
    "mean_dist_m",
    "mean_nbr_speed_mps",
)
LANE_CHANGE_LAT_SPEED_MPS: Final = 0.5


def scenario_features(batch: ScenarioBatch) -> np.ndarray:
    """Matching features (B, 6) float64 (columns in the module docstring)."""
    t0 = T0_INDEX
    ego_xy = np.nan_to_num(batch.ego_xy_m[:, t0].astype(np.float64))  # the origin by construction
    ego_v = batch.ego_vxy_mps[:, t0].astype(np.float64)
    ego_speed = np.nan_to_num(np.hypot(ego_v[:, 0], ego_v[:, 1]), nan=0.0, posinf=0.0)
    nbr_xy_t0 = batch.nbr_xy_m[:, :, t0]
    nbr_v_t0 = batch.nbr_vxy_mps[:, :, t0]
    visible = batch.nbr_valid[:, :, t0] & np.isfinite(nbr_xy_t0).all(axis=-1) & np.isfinite(nbr_v_t0).all(axis=-1)
    n_vis = visible.sum(axis=1)
    nbr_xy = batch.nbr_xy_m[:, :, t0].astype(np.float64)
    dist = np.hypot(nbr_xy[..., 0] - ego_xy[:, None, 0], nbr_xy[..., 1] - ego_xy[:, None, 1])
    dist = np.where(visible, dist, np.nan)
    nbr_v = batch.nbr_vxy_mps[:, :, t0].astype(np.float64)
    nbr_speed = np.where(visible, np.hypot(nbr_v[..., 0], nbr_v[..., 1]), np.nan)
    has = n_vis > 0
    safe_n = np.maximum(n_vis, 1)
    min_dist = np.where(has, np.nanmin(np.where(visible, dist, np.inf), axis=1), NEIGHBOUR_RADIUS_M)
    mean_dist = np.where(has, np.nansum(dist, axis=1) / safe_n, NEIGHBOUR_RADIUS_M)
    mean_speed = np.where(has, np.nansum(nbr_speed, axis=1) / safe_n, ego_speed)
    hist_lanes = batch.ego_lane_id[:, : t0 + 1]
    changed = np.any(hist_lanes != hist_lanes[:, :1], axis=1)
    lane_change = changed | (np.abs(np.nan_to_num(ego_v[:, 1])) > LANE_CHANGE_LAT_SPEED_MPS)
    return np.stack(
        [n_vis.astype(np.float64), ego_speed, lane_change.astype(np.float64), min_dist, mean_dist, mean_speed],
        axis=1,
    )
