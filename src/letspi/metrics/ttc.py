"""1-D time-to-collision with the preceding vehicle (paper §IV-C "TTC"), and rear TTC.

Preceding at step f: of the valid neighbours ahead (dx > 0) whose boxes overlap the ego's laterally
(|dy| < (W_ego + W_nbr) / 2), the one with the smallest dx, so it follows the planned ego between lanes. Gap
s = dx - (L_ego + L_nbr) / 2, dv = vx_ego - vx_nbr; TTC = 0 if s <= 0, s / dv if dv > 0, else +inf. Rear TTC
mirrors it for the nearest follower (dx < 0): s = -dx - (L_ego + L_nbr) / 2, dv = vx_nbr - vx_ego.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from letspi.conflict import time_to_collision_s
from letspi.metrics.inputs import MetricInputs, min_over_time


@dataclass(frozen=True)
class PrecedingVehicle:
    """The preceding (or, for the rear TTC, following) vehicle per step, (B, F) each: ``nbr`` slot (-1 none),
    ``gap_m`` bumper gap (+inf none), ``closing_mps`` how fast the gap shrinks (NaN none)."""

    nbr: np.ndarray
    gap_m: np.ndarray
    closing_mps: np.ndarray


@dataclass(frozen=True)
class TTCResult:
    """``ttc_s`` (B, F); ``min_ttc_s`` (B,) with ``min_ttc_step`` / ``min_ttc_nbr`` (-1 if inf); ``preceding`` the
    vehicle it is taken with (the follower for ``rear_ttc_1d``)."""

    ttc_s: np.ndarray
    preceding: PrecedingVehicle
    min_ttc_s: np.ndarray
    min_ttc_step: np.ndarray
    min_ttc_nbr: np.ndarray


def _path_vehicle(inp: MetricInputs, *, ahead: bool) -> PrecedingVehicle:
    """Nearest valid neighbour in the ego's path (lateral box overlap) ahead of or behind the ego."""
    sign = 1.0 if ahead else -1.0
    dist = sign * inp.dx_m  # centre distance along the direction looked in
    cand = inp.lateral_overlap & (dist > 0)
    dist_c = np.where(cand, dist, np.inf)
    nbr = dist_c.argmin(axis=1)[:, None, :]  # (B, 1, F)
    has = np.take_along_axis(cand, nbr, axis=1)[:, 0]
    d = np.take_along_axis(dist_c, nbr, axis=1)[:, 0]
    half_len = np.take_along_axis(np.broadcast_to(inp.half_len_sum_m, dist.shape), nbr, axis=1)[:, 0]
    vx_n = np.take_along_axis(inp.nbr_vxy_mps[..., 0], nbr, axis=1)[:, 0]
    gap = np.where(has, d - half_len, np.inf)
    closing = np.where(has, sign * (inp.ego_vxy_mps[..., 0] - vx_n), np.nan)
    return PrecedingVehicle(nbr=np.where(has, nbr[:, 0], -1), gap_m=gap, closing_mps=closing)


def preceding_vehicle(inp: MetricInputs) -> PrecedingVehicle:
    """The preceding vehicle of the (planned) ego at every step (module doc)."""
    return _path_vehicle(inp, ahead=True)


def following_vehicle(inp: MetricInputs) -> PrecedingVehicle:
    """The following vehicle in the (planned) ego's path at every step (module doc)."""
    return _path_vehicle(inp, ahead=False)


def ttc_from_gap(gap_m: np.ndarray, closing_mps: np.ndarray) -> np.ndarray:
    """TTC [s] from bumper gap [m] and closing speed [m/s]: 0 if gap <= 0, gap/dv if dv > 0, else (or NaN dv) +inf."""
    return time_to_collision_s(gap_m, closing_mps, contact_s=0.0, not_closing_s=np.inf)


def _ttc_of(path: PrecedingVehicle) -> TTCResult:
    ttc = ttc_from_gap(path.gap_m, path.closing_mps)
    val, step = min_over_time(ttc)
    nbr = np.where(step >= 0, np.take_along_axis(path.nbr, np.maximum(step, 0)[:, None], axis=1)[:, 0], -1)
    return TTCResult(ttc_s=ttc, preceding=path, min_ttc_s=val, min_ttc_step=step, min_ttc_nbr=nbr)


def ttc_1d(inp: MetricInputs) -> TTCResult:
    """Per-step 1-D TTC with the preceding vehicle and its per-scenario minimum."""
    return _ttc_of(preceding_vehicle(inp))


def rear_ttc_1d(inp: MetricInputs) -> TTCResult:
    """Per-step 1-D TTC of the following vehicle in the ego's path and its minimum (module doc)."""
    return _ttc_of(following_vehicle(inp))
