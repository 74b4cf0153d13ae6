"""Deceleration rate to avoid a crash with the preceding vehicle (as defined in ``letspi.metrics.ttc``).

DRAC = dv² / (2 s) [m/s²], s the bumper gap, dv = vx_ego - vx_nbr > 0; 0 without a preceding vehicle or when not
closing; +inf when the boxes already overlap. SUMO flags DRAC > 3.0 m/s².
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from letspi.conflict import deceleration_to_avoid_crash_mps2
from letspi.metrics.inputs import MetricInputs, min_over_time
from letspi.metrics.ttc import PrecedingVehicle, preceding_vehicle


@dataclass(frozen=True)
class DRACResult:
    """drac_mps2 (B, F); max_drac_mps2 (B,) with max_drac_step / max_drac_nbr (-1 when max is 0)."""

    drac_mps2: np.ndarray
    max_drac_mps2: np.ndarray
    max_drac_step: np.ndarray
    max_drac_nbr: np.ndarray


def drac_from_gap(gap_m: np.ndarray, closing_mps: np.ndarray) -> np.ndarray:
    """DRAC [m/s^2] from bumper gap [m] and closing speed [m/s] (inf gap or NaN speed -> 0)."""
    return deceleration_to_avoid_crash_mps2(gap_m, closing_mps, contact_mps2=np.inf)


def drac(inp: MetricInputs, preceding: PrecedingVehicle | None = None) -> DRACResult:
    """Per-step DRAC and its per-scenario maximum (``preceding`` reuses ``ttc_1d``'s result)."""
    prec = preceding if preceding is not None else preceding_vehicle(inp)
    d = drac_from_gap(prec.gap_m, prec.closing_mps)
    val, step = min_over_time(d, maximise=True)
    step = np.where(val > 0, step, -1)
    nbr = np.where(step >= 0, np.take_along_axis(prec.nbr, np.maximum(step, 0)[:, None], axis=1)[:, 0], -1)
    return DRACResult(drac_mps2=d, max_drac_mps2=val, max_drac_step=step, max_drac_nbr=nbr)
