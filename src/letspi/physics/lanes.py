"""Lane geometry from the ego-frame markings: lines ``y = marking_y_m`` (B, M), ascending from the right road edge,
NaN padded; lane k lies between markings k and k + 1.
"""

from __future__ import annotations

import numpy as np

DEFAULT_LANE_WIDTH_M = 3.75


def lane_centres_m(marking_y_m: np.ndarray) -> np.ndarray:
    """Lane centre y per lane, (B, M - 1); NaN where either bounding marking is padding."""
    my = np.asarray(marking_y_m, dtype=np.float64)
    return 0.5 * (my[:, 1:] + my[:, :-1])


def lane_width_m(marking_y_m: np.ndarray, default_m: float = DEFAULT_LANE_WIDTH_M) -> np.ndarray:
    """Median lane width per scenario, (B,); ``default_m`` when fewer than two markings are known."""
    my = np.asarray(marking_y_m, dtype=np.float64)
    widths = np.diff(my, axis=1)
    widths = np.where(np.isfinite(widths) & (widths > 0.5), widths, np.nan)
    out = np.full(my.shape[0], default_m)
    has = np.isfinite(widths).any(axis=1)
    if has.any():
        out[has] = np.nanmedian(widths[has], axis=1)
    return out


def lane_index_of(y_m: np.ndarray, marking_y_m: np.ndarray) -> np.ndarray:
    """Index of the lane containing ``y_m`` (B,), clipped into the road's lanes (beyond an edge: the nearest lane);
    -1 without lanes."""
    my = np.asarray(marking_y_m, dtype=np.float64)
    y = np.asarray(y_m, dtype=np.float64)
    n_markings = np.isfinite(my).sum(axis=1)
    # NaN padding sits at the end; NaN comparisons are False, so padding never counts.
    below = (my <= y[:, None]).sum(axis=1)
    n_lanes = n_markings - 1
    idx = np.clip(below - 1, 0, np.maximum(n_lanes - 1, 0))
    return np.where(n_lanes >= 1, idx, -1)


def outer_lane_centres_m(marking_y_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lowest, highest) lane centre y per scenario, (B,) each; NaN without lanes."""
    centres = lane_centres_m(marking_y_m)
    if centres.shape[1] == 0:
        nan = np.full(centres.shape[0], np.nan)
        return nan, nan.copy()
    finite = np.isfinite(centres)
    lo = np.where(finite, centres, np.inf).min(axis=1)
    hi = np.where(finite, centres, -np.inf).max(axis=1)
    return np.where(np.isfinite(lo), lo, np.nan), np.where(np.isfinite(hi), hi, np.nan)
