"""Physical contact in a HighD recording: pairs of boxes whose x and y intervals both overlap with positive length
in the same frame (touching is not contact)."""

from __future__ import annotations

import numpy as np
import pandas as pd

__all__ = ["overlapping_boxes"]

_OVERLAP_COLUMNS = ["frame", "id_a", "id_b", "overlap_x_m", "overlap_y_m"]


def overlapping_boxes(tracks: pd.DataFrame) -> pd.DataFrame:
    """All pairs of boxes with positive-area overlap in the same frame.

    ``tracks``: HighD tracks (at least ``frame, id, x, y, width, height``). Returns one row per pair and frame:
    ``frame``, ``id_a`` < ``id_b``, ``overlap_x_m``, ``overlap_y_m`` [m], sorted by (frame, id_a, id_b); empty
    (with these columns) when no boxes overlap."""
    if len(tracks) == 0:
        return pd.DataFrame(columns=_OVERLAP_COLUMNS)
    frame = tracks["frame"].to_numpy(np.int64)
    x0 = tracks["x"].to_numpy(np.float64)
    x1 = x0 + tracks["width"].to_numpy(np.float64)
    y0 = tracks["y"].to_numpy(np.float64)
    y1 = y0 + tracks["height"].to_numpy(np.float64)
    ids = tracks["id"].to_numpy(np.int64)

    # One sortable key per row: frames are separated by more than the whole x extent.
    span = float(np.max(x1) - np.min(x0)) + 1.0
    base = x0.min()
    key_start = frame * span + (x0 - base)
    order = np.argsort(key_start, kind="stable")
    key_sorted = key_start[order]
    key_end = (frame * span + (x1 - base))[order]
    # Successors of sorted row i that start strictly before its right edge (same frame by construction).
    stop = np.searchsorted(key_sorted, key_end, side="left")
    counts = np.maximum(stop - np.arange(len(order)) - 1, 0)
    if counts.sum() == 0:
        return pd.DataFrame(columns=_OVERLAP_COLUMNS)
    a = np.repeat(np.arange(len(order)), counts)
    # Offsets 1..count within each run: position minus the run start.
    run_start = np.repeat(np.cumsum(counts) - counts, counts)
    b = a + 1 + (np.arange(len(a)) - run_start)
    ra, rb = order[a], order[b]
    ox = np.minimum(x1[ra], x1[rb]) - np.maximum(x0[ra], x0[rb])
    oy = np.minimum(y1[ra], y1[rb]) - np.maximum(y0[ra], y0[rb])
    hit = (ox > 0.0) & (oy > 0.0) & (frame[ra] == frame[rb])
    ra, rb, ox, oy = ra[hit], rb[hit], ox[hit], oy[hit]
    lo = np.minimum(ids[ra], ids[rb])
    hi = np.maximum(ids[ra], ids[rb])
    out = pd.DataFrame({"frame": frame[ra], "id_a": lo, "id_b": hi, "overlap_x_m": ox, "overlap_y_m": oy})
    return out.sort_values(["frame", "id_a", "id_b"], kind="stable").reset_index(drop=True)
