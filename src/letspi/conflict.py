"""Surrogate safety measures of a car-following pair from bumper gap s [m] and closing speed dv [m/s], element-wise.

TTC [s] = s / dv and DRAC [m/s²] = dv² / (2 s) while closing in (s > 0, dv > 0; NaN dv is not closing).
"""

from __future__ import annotations

import numpy as np


def time_to_collision_s(gap_m: np.ndarray, closing_mps: np.ndarray, *, contact_s: float = 0.0,
                        not_closing_s: float = np.inf) -> np.ndarray:
    """TTC [s] = gap / closing speed while closing in; ``contact_s`` where the gap is <= 0 (boxes
    touch), ``not_closing_s`` where the follower is not closing in (or the speed is NaN)."""
    gap = np.asarray(gap_m, dtype=np.float64)
    closing = np.asarray(closing_mps, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc = np.where(closing > 0, gap / closing, not_closing_s)
        return np.where(gap <= 0, contact_s, ttc)


def deceleration_to_avoid_crash_mps2(gap_m: np.ndarray, closing_mps: np.ndarray, *,
                                     contact_mps2: float = np.inf) -> np.ndarray:
    """DRAC [m/s²] = closing speed² / (2 gap) while closing in; ``contact_mps2`` where the gap is
    finite and <= 0 (no finite deceleration avoids a contact that happened); 0 where not closing in,
    or with no vehicle ahead (gap +inf, speed NaN)."""
    gap = np.asarray(gap_m, dtype=np.float64)
    closing = np.nan_to_num(np.asarray(closing_mps, dtype=np.float64), nan=0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        drac = np.where((closing > 0) & (gap > 0), closing**2 / (2.0 * gap), 0.0)
        return np.where(np.isfinite(gap) & (gap <= 0), contact_mps2, drac)
