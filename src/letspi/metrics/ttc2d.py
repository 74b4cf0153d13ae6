"""2-D time-to-collision of axis-aligned boxes under constant relative velocity [s].

Per pair and step, with p = c_nbr - c_ego and v = v_nbr - v_ego, the boxes overlap along an axis while
|p + v t| < h (half-size sum). TTC is the first time both axes overlap, if that is before both exits and the
overlap is not past (0 when already overlapping); otherwise +inf.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from letspi.metrics.inputs import MetricInputs, min_over_nbr_time


@dataclass(frozen=True)
class TTC2DResult:
    """ttc_s (B, N, F); min_ttc2d_s (B,) with min_ttc2d_step / min_ttc2d_nbr (B,), -1 if inf."""

    ttc_s: np.ndarray
    min_ttc2d_s: np.ndarray
    min_ttc2d_step: np.ndarray
    min_ttc2d_nbr: np.ndarray


def _axis_interval(p: np.ndarray, v: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Open time interval (entry, exit) in which |p + v t| < h, elementwise."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-h - p) / v
        t2 = (h - p) / v
    entry = np.minimum(t1, t2)
    exit_ = np.maximum(t1, t2)
    still = v == 0
    inside = np.abs(p) < h
    entry = np.where(still, np.where(inside, -np.inf, np.inf), entry)
    exit_ = np.where(still, np.where(inside, np.inf, -np.inf), exit_)
    return entry, exit_


def box_ttc_2d(
    px: np.ndarray, py: np.ndarray, vx: np.ndarray, vy: np.ndarray, hx: np.ndarray, hy: np.ndarray
) -> np.ndarray:
    """2-D TTC [s] of two boxes from relative position and velocity and half-size sums; broadcasts, NaN gives +inf."""
    ex, xx = _axis_interval(px, vx, hx)
    ey, xy = _axis_interval(py, vy, hy)
    entry = np.maximum(ex, ey)
    exit_ = np.minimum(xx, xy)
    hit = (entry < exit_) & (exit_ > 0)  # False for NaN
    return np.where(hit, np.maximum(entry, 0.0), np.inf)


def ttc_2d(inp: MetricInputs) -> TTC2DResult:
    """2-D TTC of the planned ego against every valid neighbour at every step."""
    rel_v = inp.nbr_vxy_mps - inp.ego_vxy_mps[:, None]
    ttc = box_ttc_2d(inp.dx_m, inp.dy_m, rel_v[..., 0], rel_v[..., 1], inp.half_len_sum_m, inp.half_wid_sum_m)
    ttc = np.where(inp.nbr_valid, ttc, np.inf)
    val, step, nbr = min_over_nbr_time(ttc)
    return TTC2DResult(ttc_s=ttc, min_ttc2d_s=val, min_ttc2d_step=step, min_ttc2d_nbr=nbr)
