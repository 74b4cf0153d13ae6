"""Driver parameters of reactive neighbours from their (simulated) history: the highest speed driven, and a low
quantile of the time gaps to an in-path leader (low, so free-driving frames do not inflate it)."""

from __future__ import annotations

import numpy as np

from letspi.physics.idm import desired_speed_from_history
from letspi.simulation.config import DriverModelConfig

MIN_SPEED_FOR_HEADWAY_MPS = 1.0


def estimate_driver_params(xy_m: np.ndarray, vx_mps: np.ndarray, valid: np.ndarray, length_m: np.ndarray,
                           width_m: np.ndarray, config: DriverModelConfig) -> tuple[np.ndarray, np.ndarray]:
    """Desired speed [m/s] and time headway [s], two (K, V) float64 arrays, of every vehicle of K scenarios. xy_m:
    (K, V, H, 2) box centres over H history frames (NaN where absent); vx_mps: (K, V, H); valid: (K, V, H); length_m,
    width_m: (K, V). Every vehicle, the ego included, may be a leader."""
    xy = np.asarray(xy_m, dtype=np.float64)
    ok = np.asarray(valid, dtype=bool) & np.isfinite(xy).all(axis=-1)
    vx = np.where(ok, np.asarray(vx_mps, dtype=np.float64), np.nan)
    lo, hi = config.desired_speed_bounds_mps
    desired = np.clip(desired_speed_from_history(vx, ok), lo, hi)

    length = np.asarray(length_m, dtype=np.float64)
    width = np.asarray(width_m, dtype=np.float64)
    # pairwise follower f, leader l: (K, V_f, V_l, H)
    dx = xy[:, None, :, :, 0] - xy[:, :, None, :, 0]
    dy = xy[:, None, :, :, 1] - xy[:, :, None, :, 1]
    half_len = 0.5 * (length[:, :, None] + length[:, None, :])[..., None]
    half_wid = 0.5 * (width[:, :, None] + width[:, None, :])[..., None]
    pair_ok = ok[:, :, None, :] & ok[:, None, :, :]
    v = vx.shape[1]
    pair_ok &= ~np.eye(v, dtype=bool)[None, :, :, None]
    in_path = pair_ok & (np.abs(dy) < half_wid) & (dx > 0)
    gap = np.where(in_path, dx - half_len, np.inf)
    nearest = gap.min(axis=2)  # (K, V, H): bumper gap to the nearest in-path leader
    speed = np.where(np.isfinite(vx), vx, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        time_gap = np.where((speed > MIN_SPEED_FOR_HEADWAY_MPS) & np.isfinite(nearest) & (nearest > 0),
                            nearest / speed, np.nan)
    time_gap = np.where(time_gap < config.max_leader_gap_s, time_gap, np.nan)
    has = np.asarray(np.isfinite(time_gap).any(axis=-1))
    # rows without any observed gap get a constant (no all-NaN slice); they take the default below
    q = np.nanquantile(np.where(has[..., None], time_gap, config.default_headway_s), config.headway_quantile, axis=-1)
    headway = np.where(has, q, config.default_headway_s)
    headway = np.clip(np.nan_to_num(headway, nan=config.default_headway_s), *config.headway_bounds_s)
    return desired, headway
