"""Post-encroachment time by the grid method (Allen et al. 1978).

Cells of ``cell_m`` in the ego frame; a box occupies a cell when it strictly covers the cell's **centre**. For a
cell both vehicles occupy within the F future steps, PET = t_enter(second) - t_exit(first), 0 when the
occupancies overlap in time; a pair's PET is the minimum over shared cells, a scenario's over neighbours, +inf
when no cell is shared. Every valid neighbour counts, in either order; history is not used. ``cell_m`` must not
exceed the smallest vehicle dimension. Computed as dt · min |f1 - f2| over frame pairs whose boxes share a cell.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from letspi.constants import DT_S
from letspi.metrics.inputs import MetricInputs

_CLIP = 1 << 30  # |cell index| bound; boxes beyond (5e8 m at 0.5 m cells) count as absent
_NONE = 1 << 31  # sentinel: "covers no cell" (lo index +_NONE, hi index -_NONE)
_NO_FRAME = 1 << 20  # sentinel frame index / frame distance


@dataclass(frozen=True)
class PETResult:
    """Per pair (B, N): ``pet_s`` (+inf undefined), ``pet_step`` (the second vehicle enters the conflict cell, -1
    undefined), ``ego_first``. Per scenario (B,): ``min_pet_s``, ``min_pet_step``, ``min_pet_nbr`` (-1 undefined)."""

    pet_s: np.ndarray
    pet_step: np.ndarray
    ego_first: np.ndarray
    min_pet_s: np.ndarray
    min_pet_step: np.ndarray
    min_pet_nbr: np.ndarray


def _cell_range(lo_m: np.ndarray, hi_m: np.ndarray, cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """First and last cell (int64) whose centre (i + 1/2) c lies strictly inside (lo, hi); the empty range
    (+_NONE, -_NONE) for non-finite input or no centre covered."""
    with np.errstate(invalid="ignore"):
        i0 = np.floor(lo_m / cell_m - 0.5) + 1.0
        i1 = np.ceil(hi_m / cell_m - 0.5) - 1.0
    ok = (i0 <= i1) & (np.abs(i0) <= _CLIP) & (np.abs(i1) <= _CLIP)  # False for NaN / inf
    return np.where(ok, i0, _NONE).astype(np.int64), np.where(ok, i1, -_NONE).astype(np.int64)


def _batched_searchsorted(a: np.ndarray, v: np.ndarray, side: str) -> np.ndarray:
    """Row-wise ``np.searchsorted(a[p], v[p], side)`` for int64 (P, F) arrays with sorted rows."""
    p, f = a.shape
    if p == 0:
        return np.zeros_like(v)
    low = min(int(a.min()), int(v.min()))
    span = max(int(a.max()), int(v.max())) - low + 1
    # shifting each row into its own value block turns P searches into one flat search
    off = np.arange(p, dtype=np.int64)[:, None] * span
    flat = np.searchsorted((a - low + off).ravel(), (v - low + off).ravel(), side=side)  # type: ignore[call-overload]
    return flat.reshape(v.shape) - np.arange(p, dtype=np.int64)[:, None] * f


def pet_grid(inp: MetricInputs, cell_m: float = 0.5, dt_s: float = DT_S) -> PETResult:
    """Grid PET of the planned ego against every neighbour (definition and algorithm: module doc)."""
    b, n, _ = inp.nbr_valid.shape
    ex, ey = inp.ego_xy_m[..., 0], inp.ego_xy_m[..., 1]
    hl, hw = 0.5 * inp.ego_length_m[:, None], 0.5 * inp.ego_width_m[:, None]
    ex0, ex1 = _cell_range(ex - hl, ex + hl, cell_m)  # (B, F)
    ey0, ey1 = _cell_range(ey - hw, ey + hw, cell_m)
    nx = np.where(inp.nbr_valid, inp.nbr_xy_m[..., 0], np.nan)
    ny = np.where(inp.nbr_valid, inp.nbr_xy_m[..., 1], np.nan)
    nhl, nhw = 0.5 * inp.nbr_length_m[..., None], 0.5 * inp.nbr_width_m[..., None]
    nx0, nx1 = _cell_range(nx - nhl, nx + nhl, cell_m)  # (B, N, F)
    ny0, ny1 = _cell_range(ny - nhw, ny + nhw, cell_m)

    # Candidate pairs: the swept cell bounding boxes intersect (cheap pruning)
    e_r0, e_r1 = ey0.min(axis=1), ey1.max(axis=1)
    e_c0, e_c1 = ex0.min(axis=1), ex1.max(axis=1)
    cand = (
        (ny0.min(axis=2) <= e_r1[:, None])
        & (ny1.max(axis=2) >= e_r0[:, None])
        & (nx0.min(axis=2) <= e_c1[:, None])
        & (nx1.max(axis=2) >= e_c0[:, None])
    )
    bi, ni = np.nonzero(cand)

    pet_s = np.full((b, n), np.inf)
    pet_step = np.full((b, n), -1, dtype=np.int64)
    ego_first = np.zeros((b, n), dtype=bool)
    if bi.size:
        best, f1, f2 = _pair_min_frame_distance(
            ex0[bi], ex1[bi], ey0[bi], ey1[bi], nx0[bi, ni], nx1[bi, ni], ny0[bi, ni], ny1[bi, ni], e_r0[bi], e_r1[bi]
        )
        found = best < _NO_FRAME
        pet_s[bi, ni] = np.where(found, best * dt_s, np.inf)
        pet_step[bi, ni] = np.where(found, np.maximum(f1, f2), -1)
        ego_first[bi, ni] = found & (f1 < f2)

    k = pet_s.argmin(axis=1) if n else np.zeros(b, dtype=np.int64)
    min_pet = pet_s[np.arange(b), k] if n else np.full(b, np.inf)
    has = np.isfinite(min_pet)
    return PETResult(
        pet_s=pet_s,
        pet_step=pet_step,
        ego_first=ego_first,
        min_pet_s=min_pet,
        min_pet_step=np.where(has, pet_step[np.arange(b), k] if n else -1, -1),
        min_pet_nbr=np.where(has, k, -1),
    )


def _pair_min_frame_distance(
    ex0: np.ndarray,
    ex1: np.ndarray,
    ey0: np.ndarray,
    ey1: np.ndarray,
    nx0: np.ndarray,
    nx1: np.ndarray,
    ny0: np.ndarray,
    ny1: np.ndarray,
    row0: np.ndarray,
    row1: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """min |f1 - f2| over frames where the ego's (f1) and the neighbour's (f2) cell rectangles intersect, from (P, F)
    cell ranges per pair and the ego's row span (P,); (distance, f1, f2) (P,), distance >= _NO_FRAME when never."""
    p, f = ex0.shape
    frames = np.broadcast_to(np.arange(f, dtype=np.int64), (p, f))
    # Neighbour frames whose columns meet the ego's columns at f1: lo = first f2 with
    # nx1(f2) >= ex0(f1); hi = last f2 with nx0(f2) <= ex1(f1). Running max / reverse running
    # min make the rows sorted without changing these two answers.
    lo = _batched_searchsorted(np.maximum.accumulate(nx1, axis=1), ex0, "left")
    hi = _batched_searchsorted(np.minimum.accumulate(nx0[:, ::-1], axis=1)[:, ::-1], ex1, "right") - 1
    cols_ok = lo <= hi
    g = np.clip(np.clip(frames, lo, np.maximum(hi, lo)), 0, f - 1)  # the frame in [lo, hi] nearest f1

    best = np.full(p, _NO_FRAME, dtype=np.int64)
    best_f1 = np.full(p, -1, dtype=np.int64)
    best_f2 = np.full(p, -1, dtype=np.int64)
    rows = np.where(row1 >= row0, row1 - row0 + 1, 0)
    for r in range(int(rows.max(initial=0))):  # loop over the (few) lateral cell rows of the ego
        j = (row0 + r)[:, None]
        ego_in = (ey0 <= j) & (ey1 >= j) & cols_ok
        if not ego_in.any():
            continue
        nbr_in = (ny0 <= j) & (ny1 >= j)
        nxt = np.minimum.accumulate(np.where(nbr_in, frames, _NO_FRAME)[:, ::-1], axis=1)[:, ::-1]
        prv = np.maximum.accumulate(np.where(nbr_in, frames, -_NO_FRAME), axis=1)
        c1 = np.take_along_axis(nxt, g, axis=1)  # first neighbour frame in the row at/after g
        c2 = np.take_along_axis(prv, g, axis=1)  # last one at/before g
        d1 = np.where(c1 <= hi, np.abs(c1 - frames), _NO_FRAME)
        d2 = np.where(c2 >= lo, np.abs(c2 - frames), _NO_FRAME)
        d = np.where(ego_in, np.minimum(d1, d2), _NO_FRAME)
        k = d.argmin(axis=1)
        dk = d[np.arange(p), k]
        better = dk < best
        best = np.where(better, dk, best)
        best_f1 = np.where(better, k, best_f1)
        f2k = np.where(d1 <= d2, c1, c2)[np.arange(p), k]
        best_f2 = np.where(better, f2k, best_f2)
    return best, best_f1, best_f2
