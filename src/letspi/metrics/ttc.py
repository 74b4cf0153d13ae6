"""1-D time-to-collision with the preceding vehicle (paper §IV-C "TTC"), and rear TTC.

Preceding vehicle at step f: among the valid neighbours whose centre is ahead of the ego's
centre (dx > 0) and whose box **overlaps the ego's box laterally** (|dy| < (W_ego + W_nbr) / 2),
the one with the smallest dx. The geometric choice (rather than HighD lane ids) follows the
*planned* ego, which may sit between lanes during a lane change, and needs no lane ids for
the plan; a vehicle straddling the line is preceding for both lanes it touches.

Gap s = dx - (L_ego + L_nbr) / 2 (bumper to bumper); closing speed dv = vx_ego - vx_nbr.
TTC = 0 if s <= 0 (boxes overlap: collision), s / dv if dv > 0, +inf otherwise (no preceding
vehicle, or not closing). Units: s, m, m/s. A neighbour overlapping the ego with its centre
behind the ego's is a follower, not preceding: such contacts show in ``collision`` and in the
rear TTC.

Rear TTC (``rear_ttc_1d``) is the same definition mirrored: the following vehicle at step f is the
valid neighbour with its centre behind the ego's (dx < 0), overlapping the ego's box laterally,
with the largest dx (the nearest); gap s = -dx - (L_ego + L_nbr) / 2, closing speed
dv = vx_nbr - vx_ego. It is what a lane change in front of a faster car, or hard braking in front
of a follower, costs, and what the front TTC cannot see.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from letspi.conflict import time_to_collision_s
from letspi.metrics.inputs import MetricInputs, min_over_time


@dataclass(frozen=True)
class PrecedingVehicle:
    """The preceding (or, for the rear TTC, following) vehicle per step, (B, F) each.

    nbr: slot index, -1 when none. gap_m: bumper-to-bumper gap (+inf when none).
    closing_mps: speed at which the gap shrinks, vx_ego - vx_nbr ahead, vx_nbr - vx_ego behind
    (NaN when none).
    """

    nbr: np.ndarray
    gap_m: np.ndarray
    closing_mps: np.ndarray


@dataclass(frozen=True)
class TTCResult:
    """ttc_s (B, F) per step; min_ttc_s (B,) with min_ttc_step / min_ttc_nbr (B,), -1 if inf.

    ``preceding`` is the vehicle the TTC is taken with (the follower for ``rear_ttc_1d``).
    """

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
    """Find the preceding vehicle of the (planned) ego at every step (definition: module doc)."""
    return _path_vehicle(inp, ahead=True)


def following_vehicle(inp: MetricInputs) -> PrecedingVehicle:
    """Find the following vehicle in the (planned) ego's path at every step (module doc)."""
    return _path_vehicle(inp, ahead=False)


def ttc_from_gap(gap_m: np.ndarray, closing_mps: np.ndarray) -> np.ndarray:
    """TTC [s] from bumper gap [m] and closing speed [m/s]: 0 if gap <= 0, gap/dv if dv > 0, else inf.

    NaN closing speed (no preceding vehicle) gives +inf.
    """
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
