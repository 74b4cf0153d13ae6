"""Surrogate safety measures of a car-following pair, from bumper gap and closing speed.

The one place the TTC and DRAC formulas are written; the planners' metrics
(``letspi.metrics.ttc``, ``letspi.metrics.drac``) and the highD-format derivation
(``letspi.highd.derive``, ``letspi.highd.criticality``) differ only in what they report where the
formula is undefined, which the callers pass in:

* TTC [s] = s / dv while closing in (gap s > 0 m, closing speed dv > 0 m/s);
* DRAC [m/s²] = dv² / (2 s) while closing in: the constant deceleration that just avoids contact.

Element-wise over arrays of any (broadcastable) shape; NaN closing speed counts as not closing.
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
