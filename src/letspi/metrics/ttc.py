"""1-D time-to-collision with the preceding vehicle (paper §IV-C "TTC"; REFERENCE §5).

Preceding vehicle at step f: among the valid neighbours whose centre is ahead of the ego's
centre (dx > 0) and whose box **overlaps the ego's box laterally** (|dy| < (W_ego + W_nbr) / 2),
the one with the smallest dx. The geometric choice (rather than HighD lane ids) follows the
*planned* ego, which may sit between lanes during a lane change, and needs no lane ids for
the plan; a vehicle straddling the line is preceding for both lanes it touches.

Gap s = dx - (L_ego + L_nbr) / 2 (bumper to bumper); closing speed dv = vx_ego - vx_nbr.
TTC = 0 if s <= 0 (boxes overlap: collision), s / dv if dv > 0, +inf otherwise (no preceding
vehicle, or not closing). Units: s, m, m/s. A neighbour overlapping the ego with its centre
behind the ego's is a follower, not preceding: such contacts show in ``collision``, not here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from letspi.metrics._common import MetricInputs, min_over_time


@dataclass(frozen=True)
class PrecedingVehicle:
    """The preceding vehicle per step, (B, F) each.

    nbr: slot index, -1 when none. gap_m: bumper-to-bumper gap (+inf when none).
    closing_mps: vx_ego - vx_nbr (NaN when none).
    """

    nbr: np.ndarray
    gap_m: np.ndarray
    closing_mps: np.ndarray


@dataclass(frozen=True)
class TTCResult:
    """ttc_s (B, F) per step; min_ttc_s (B,) with min_ttc_step / min_ttc_nbr (B,), -1 if inf."""

    ttc_s: np.ndarray
    preceding: PrecedingVehicle
    min_ttc_s: np.ndarray
    min_ttc_step: np.ndarray
    min_ttc_nbr: np.ndarray


def preceding_vehicle(inp: MetricInputs) -> PrecedingVehicle:
    """Find the preceding vehicle of the (planned) ego at every step (definition: module doc)."""
    dx = inp.dx_m
    cand = inp.lateral_overlap & (dx > 0)
    dx_c = np.where(cand, dx, np.inf)
    nbr = dx_c.argmin(axis=1)  # (B, F)
    has = np.take_along_axis(cand, nbr[:, None, :], axis=1)[:, 0]
    dx_p = np.take_along_axis(dx_c, nbr[:, None, :], axis=1)[:, 0]
    half_len = np.take_along_axis(np.broadcast_to(inp.half_len_sum_m, dx.shape), nbr[:, None, :], axis=1)[:, 0]
    vx_n = np.take_along_axis(inp.nbr_vxy_mps[..., 0], nbr[:, None, :], axis=1)[:, 0]
    gap = np.where(has, dx_p - half_len, np.inf)
    closing = np.where(has, inp.ego_vxy_mps[..., 0] - vx_n, np.nan)
    return PrecedingVehicle(nbr=np.where(has, nbr, -1), gap_m=gap, closing_mps=closing)


def ttc_from_gap(gap_m: np.ndarray, closing_mps: np.ndarray) -> np.ndarray:
    """TTC [s] from bumper gap [m] and closing speed [m/s]: 0 if gap <= 0, gap/dv if dv > 0, else inf.

    NaN closing speed (no preceding vehicle) gives +inf.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc = np.where(closing_mps > 0, gap_m / closing_mps, np.inf)
    return np.where(gap_m <= 0, 0.0, ttc)


def ttc_1d(inp: MetricInputs) -> TTCResult:
    """Per-step 1-D TTC with the preceding vehicle and its per-scenario minimum."""
    prec = preceding_vehicle(inp)
    ttc = ttc_from_gap(prec.gap_m, prec.closing_mps)
    val, step = min_over_time(ttc)
    nbr = np.where(step >= 0, np.take_along_axis(prec.nbr, np.maximum(step, 0)[:, None], axis=1)[:, 0], -1)
    return TTCResult(ttc_s=ttc, preceding=prec, min_ttc_s=val, min_ttc_step=step, min_ttc_nbr=nbr)
