"""Where a neighbour is relative to the ego at a step: front / rear / side (for reflection reports).

From the centre offset (dx, dy) = c_nbr - c_ego and the half-size sums (hx, hy): lateral overlap (|dy| < hy)
gives "front" if dx > 0 else "rear"; else longitudinal overlap (|dx| < hx) "side"; else the axis with the larger
box gap decides. ``left_right=True`` splits "side" into "left" (dy > 0) and "right"; "none" marks a missing slot.
"""

from __future__ import annotations

import numpy as np

from letspi.metrics.inputs import MetricInputs


def classify_offset(
    dx: np.ndarray, dy: np.ndarray, hx: np.ndarray, hy: np.ndarray, *, left_right: bool = False
) -> np.ndarray:
    """Vectorised classification (module doc) of broadcastable offsets; returns a str array."""
    dx, dy, hx, hy = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (dx, dy, hx, hy)))
    lat = np.abs(dy) < hy
    lon = np.abs(dx) < hx
    along = lat | (~lon & (np.abs(dx) - hx >= np.abs(dy) - hy))
    fr = np.where(dx > 0, "front", "rear")
    side = np.where(dy > 0, "left", "right") if left_right else np.full(dx.shape, "side")
    out = np.where(along, fr, side).astype(object)
    out[~(np.isfinite(dx) & np.isfinite(dy))] = "none"
    return out


def relative_position(inp: MetricInputs, step: np.ndarray, nbr: np.ndarray, *, left_right: bool = False) -> np.ndarray:
    """Class (B,) str of slot ``nbr[b]`` at future step ``step[b]`` (e.g. ``min_ttc_step`` / ``min_ttc_nbr``); -1 gives
    "none"."""
    b = inp.ego_xy_m.shape[0]
    ok = (np.asarray(step) >= 0) & (np.asarray(nbr) >= 0)
    s = np.where(ok, step, 0)
    k = np.where(ok, nbr, 0)
    rows = np.arange(b)
    dx = np.where(ok, inp.dx_m[rows, k, s], np.nan)
    dy = np.where(ok, inp.dy_m[rows, k, s], np.nan)
    hx = inp.half_len_sum_m[rows, k, 0]
    hy = inp.half_wid_sum_m[rows, k, 0]
    return classify_offset(dx, dy, hx, hy, left_right=left_right)
