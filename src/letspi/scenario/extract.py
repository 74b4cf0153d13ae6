"""HighD recordings → ego-centric planning scenarios (paper §IV-B).

Every vehicle with at least ``N_TOTAL`` frames yields windows from its first frame on, every ``stride_frames``.
**Neighbours** (what a planner sees) are the same-direction vehicles present at t = 0 within
``NEIGHBOUR_RADIUS_M``, the ``MAX_NEIGHBOURS`` closest first (1 mm resolution, ties: lower id): no later frame
counts, so the selection cannot leak the future. **Context vehicles** (scored, never shown to a planner) are
the other same-direction vehicles that come within ``CONTEXT_RADIUS_M`` of the ego's recorded future, closest
approach first, at most ``MAX_CONTEXT``, future frames only. The opposite carriageway never interacts.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from letspi.constants import (
    CONTEXT_RADIUS_M,
    DEFAULT_STRIDE_FRAMES,
    MAX_CONTEXT,
    MAX_NEIGHBOURS,
    N_FUTURE,
    N_TOTAL,
    NEIGHBOUR_RADIUS_M,
    T0_INDEX,
)
from letspi.highd.schema import DRIVING_DIRECTION_LOWER
from letspi.highd.types import Recording
from letspi.scenario.types import (
    CONTEXT_FIELDS,
    VEHICLE_CLASS_CAR,
    VEHICLE_CLASS_NONE,
    VEHICLE_CLASS_TRUCK,
    ScenarioBatch,
    concat_batches,
)

_CLASS_CODES = {"Car": VEHICLE_CLASS_CAR, "Truck": VEHICLE_CLASS_TRUCK}


@dataclass(frozen=True)
class WindowIndex:
    """Which windows exist, before any are extracted; arrays (W,). ``start_frame`` is the HighD frame of the window's
    first frame; t = 0 is ``start_frame + T0_INDEX``."""

    recording_id: np.ndarray
    ego_id: np.ndarray
    start_frame: np.ndarray

    def __len__(self) -> int:
        return len(self.ego_id)

    def take(self, indices: np.ndarray) -> WindowIndex:
        return WindowIndex(self.recording_id[indices], self.ego_id[indices], self.start_frame[indices])


def enumerate_windows(
    recordings: Sequence[Recording], stride_frames: int = DEFAULT_STRIDE_FRAMES
) -> WindowIndex:
    """All (recording, ego, start frame) windows of ``N_TOTAL`` frames with the given stride."""
    if stride_frames < 1:
        raise ValueError(f"stride_frames must be >= 1, got {stride_frames}")
    rec_ids, ego_ids, starts = [], [], []
    for rec in recordings:
        meta = rec.tracks_meta
        n_windows = np.maximum((meta["numFrames"].to_numpy() - N_TOTAL) // stride_frames + 1, 0)
        ids = np.repeat(meta["id"].to_numpy(), n_windows)
        first = np.repeat(meta["initialFrame"].to_numpy(), n_windows)
        # offset k * stride within each vehicle's run of windows
        run_start = np.repeat(np.cumsum(n_windows) - n_windows, n_windows)
        k = np.arange(int(n_windows.sum())) - run_start
        rec_ids.append(np.full(len(ids), rec.recording_id, dtype=np.int32))
        ego_ids.append(ids.astype(np.int32))
        starts.append((first + k * stride_frames).astype(np.int32))
    if not rec_ids:
        empty = np.zeros(0, dtype=np.int32)
        return WindowIndex(empty, empty, empty)
    return WindowIndex(np.concatenate(rec_ids), np.concatenate(ego_ids), np.concatenate(starts))


CRITICAL_TTC_S = 3.0
CRITICAL_DRAC_MPS2 = 3.0
EVENT_LEAD_FRAMES = 50
"""An event that started up to 2 s before t = 0 still unfolds in the window's future."""


def critical_windows(
    recordings: Sequence[Recording],
    windows: WindowIndex,
    events: Mapping[int, pd.DataFrame | None] | None = None,
) -> np.ndarray:
    """(W,) bool: whether each window's recorded *future* holds a conflict of its ego (for selecting scenarios only):
    a frame with HighD's ``ttc`` (> 0) below ``CRITICAL_TTC_S`` or DRAC = closing / (2 TTC) above
    ``CRITICAL_DRAC_MPS2``, or a scripted event (``events``: recording id -> ``NN_events.csv``) with the ego as
    ``id`` or ``other_id`` starting at most ``EVENT_LEAD_FRAMES`` before t = 0."""
    out = np.zeros(len(windows), dtype=bool)
    for rec in recordings:
        sel = np.flatnonzero(windows.recording_id == rec.recording_id)
        if not len(sel):
            continue
        t = rec.tracks.sort_values(["id", "frame"], kind="stable")
        ttc = t["ttc"].to_numpy(np.float64)
        closing = np.abs(t["xVelocity"].to_numpy(np.float64) - t["precedingXVelocity"].to_numpy(np.float64))
        defined = ttc > 0
        drac = np.where(defined, closing / (2.0 * np.where(defined, ttc, 1.0)), 0.0)
        crit = defined & ((ttc < CRITICAL_TTC_S) | (drac > CRITICAL_DRAC_MPS2))
        counts = np.concatenate([[0], np.cumsum(crit)])
        ids = t["id"].to_numpy(np.int64)
        first_row = {int(v): int(i) for v, i in zip(*np.unique(ids, return_index=True), strict=True)}
        first_frame = dict(zip(rec.tracks_meta["id"].astype(int), rec.tracks_meta["initialFrame"].astype(int),
                               strict=True))
        ego, start = windows.ego_id[sel].astype(np.int64), windows.start_frame[sel].astype(np.int64)
        base = np.array([first_row[int(e)] for e in ego]) + start - np.array([first_frame[int(e)] for e in ego])
        begin, end = base + T0_INDEX + 1, base + N_TOTAL  # future rows [begin, end)
        hit = counts[end] - counts[begin] > 0
        ev = None if events is None else events.get(rec.recording_id)
        if ev is not None and len(ev):
            frame0 = start + T0_INDEX
            ev_frame = ev["frame"].to_numpy(np.int64)
            involved = [(ev["id"].to_numpy(np.int64) == e) | (ev["other_id"].to_numpy(np.int64) == e) for e in ego]
            hit |= np.array([bool(np.any(inv & (ev_frame >= f0 - EVENT_LEAD_FRAMES) & (ev_frame < f0 + N_FUTURE)))
                             for inv, f0 in zip(involved, frame0, strict=True)], dtype=bool)
        out[sel] = hit
    return out


def sample_windows(
    windows: WindowIndex,
    max_n: int | None,
    seed: int,
    critical: np.ndarray | None = None,
    critical_share: float = 0.0,
) -> WindowIndex:
    """Up to ``max_n`` windows drawn without replacement by ``seed``: uniform (the paper), or with ``critical`` (W,) and
    ``critical_share`` F, round(F · max_n) of them critical; sorted by (recording, ego, start)."""
    if not 0.0 <= critical_share <= 1.0:
        raise ValueError(f"critical_share must be in [0, 1], got {critical_share}")
    n = len(windows)
    rng = np.random.default_rng(seed)
    if max_n is None or max_n >= n:
        chosen = np.arange(n)
    elif critical is None or critical_share == 0.0:
        chosen = np.sort(rng.choice(n, size=max_n, replace=False))
    else:
        crit = np.flatnonzero(critical)
        n_crit = min(round(critical_share * max_n), len(crit))
        from_crit = rng.choice(crit, size=n_crit, replace=False)
        rest = np.setdiff1d(np.arange(n), from_crit)
        chosen = np.sort(np.concatenate([from_crit, rng.choice(rest, size=max_n - n_crit, replace=False)]))
    sub = windows.take(chosen)
    order = np.lexsort((sub.start_frame, sub.ego_id, sub.recording_id))
    return sub.take(order)


class _RecordingArrays:
    """A recording's tracks as flat NumPy arrays sorted by (frame, id), plus per-vehicle metadata."""

    def __init__(self, rec: Recording) -> None:
        t = rec.tracks.sort_values(["frame", "id"], kind="stable")
        self.frame = t["frame"].to_numpy(np.int64)
        self.vid = t["id"].to_numpy(np.int64)
        self.cx = (t["x"] + t["width"] / 2.0).to_numpy(np.float64)
        self.cy = (t["y"] + t["height"] / 2.0).to_numpy(np.float64)
        self.vx = t["xVelocity"].to_numpy(np.float64)
        self.vy = t["yVelocity"].to_numpy(np.float64)
        self.ax = t["xAcceleration"].to_numpy(np.float64)
        self.ay = t["yAcceleration"].to_numpy(np.float64)
        self.lane = t["laneId"].to_numpy(np.int64)
        meta = rec.tracks_meta.set_index("id")
        max_id = int(max(meta.index.max(), self.vid.max() if len(self.vid) else 0))
        self.direction = np.zeros(max_id + 1, dtype=np.int8)
        self.direction[meta.index.to_numpy()] = meta["drivingDirection"].to_numpy()
        self.vclass = np.full(max_id + 1, VEHICLE_CLASS_NONE, dtype=np.int8)
        self.vclass[meta.index.to_numpy()] = [_CLASS_CODES.get(str(c), VEHICLE_CLASS_CAR) for c in meta["class"]]
        self.length = np.zeros(max_id + 1, dtype=np.float32)
        self.length[meta.index.to_numpy()] = meta["width"].to_numpy()
        self.width = np.zeros(max_id + 1, dtype=np.float32)
        self.width[meta.index.to_numpy()] = meta["height"].to_numpy()
        # rows of frame f are [frame_start[f - f_min], frame_start[f - f_min + 1])
        self.f_min = int(self.frame.min()) if len(self.frame) else 1
        f_max = int(self.frame.max()) if len(self.frame) else 0
        self.frame_start = np.searchsorted(self.frame, np.arange(self.f_min, f_max + 2))

    def rows_of_frames(self, first: int, last: int) -> slice:
        """Row slice of all vehicles in frames ``first..last`` (inclusive)."""
        return slice(int(self.frame_start[first - self.f_min]), int(self.frame_start[last - self.f_min + 1]))


def recording_key(rec: Recording) -> str:
    """A short content hash of a recording (its meta and every vehicle's meta row), wherever it is read from."""
    return recording_key_of(rec.meta, rec.tracks_meta)


def recording_key_of(meta: Mapping[str, object], tracks_meta: pd.DataFrame) -> str:
    """``recording_key`` from a recording's meta and tracks meta (``letspi.highd.io.read_recording_meta``)."""
    h = hashlib.blake2b(digest_size=8)
    h.update(repr(sorted((str(k), str(v)) for k, v in meta.items())).encode())
    h.update(pd.util.hash_pandas_object(tracks_meta, index=False).to_numpy().tobytes())
    return h.hexdigest()


def _to_ego_frame(
    direction: int, cx: np.ndarray, cy: np.ndarray, cx0: float, cy0: float
) -> tuple[np.ndarray, np.ndarray]:
    if direction == DRIVING_DIRECTION_LOWER:
        return cx - cx0, -(cy - cy0)
    return -(cx - cx0), cy - cy0


def _sign(direction: int) -> tuple[float, float]:
    """Multipliers (x, y) taking image-axis velocities/accelerations into the ego frame."""
    return (1.0, -1.0) if direction == DRIVING_DIRECTION_LOWER else (-1.0, 1.0)


def _road_arrays(rec: Recording, direction: int, cy0: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Markings (ascending ego y), edge flags and lane ids of the ego's carriageway."""
    upper, lower = rec.upper_markings_y_m, rec.lower_markings_y_m
    all_markings = np.sort(np.concatenate([upper, lower]))
    own = lower if direction == DRIVING_DIRECTION_LOWER else upper
    _, y = _to_ego_frame(direction, np.zeros_like(own), own, 0.0, cy0)
    order = np.argsort(y)
    y_sorted = y[order]
    own_sorted = own[order]
    edge = np.zeros(len(own), dtype=bool)
    edge[[0, -1]] = True
    mid_image_y = 0.5 * (own_sorted[:-1] + own_sorted[1:])
    lane_ids = (1 + np.searchsorted(all_markings, mid_image_y)).astype(np.int8)
    return y_sorted.astype(np.float32), edge, lane_ids


@dataclass(frozen=True)
class _WindowView:
    """The recording rows of one window (``sl``) in the ego frame: frame offset (0..199), vehicle id,
    x and y [m] per row, and the signs taking image-axis velocities into the ego frame."""

    sl: slice
    fr: np.ndarray
    vid: np.ndarray
    ex: np.ndarray
    ey: np.ndarray
    sx: float
    sy: float


def _neighbours_and_context(arr: _RecordingArrays, view: _WindowView, is_ego: np.ndarray, ego_rows: np.ndarray,
                            direction: int) -> tuple[np.ndarray, np.ndarray]:
    """Vehicle ids of the window's neighbours, nearest first, and of its context vehicles, closest approach first
    (module doc)."""
    fr, vid = view.fr, view.vid
    ego_x_at, ego_y_at = view.ex[ego_rows], view.ey[ego_rows]
    dist = np.hypot(view.ex - ego_x_at[fr], view.ey - ego_y_at[fr])
    same_dir = (~is_ego) & (arr.direction[vid] == direction)
    at_t0 = same_dir & (fr == T0_INDEX) & (dist <= NEIGHBOUR_RADIUS_M)
    order = np.lexsort((vid[at_t0], np.round(dist[at_t0], 3)))
    keep = vid[at_t0][order][:MAX_NEIGHBOURS]
    future_rows = same_dir & (fr > T0_INDEX) & (dist <= CONTEXT_RADIUS_M) & ~np.isin(vid, keep)
    ctx = np.zeros(0, dtype=np.int64)
    if future_rows.any():
        uniq, inv = np.unique(vid[future_rows], return_inverse=True)
        min_d = np.full(len(uniq), np.inf)
        np.minimum.at(min_d, inv, dist[future_rows])
        ctx = uniq[np.lexsort((uniq, np.round(min_d, 3)))][:MAX_CONTEXT]
    return keep, ctx


def _store_ego(out: dict[str, np.ndarray], w: int, ego: int, ego_rows: np.ndarray, arr: _RecordingArrays,
               view: _WindowView) -> None:
    """The ego's class, size and track into window ``w`` of ``out``."""
    out["ego_class"][w] = arr.vclass[ego]
    out["ego_length_m"][w] = arr.length[ego]
    out["ego_width_m"][w] = arr.width[ego]
    out["ego_xy_m"][w, :, 0] = view.ex[ego_rows]
    out["ego_xy_m"][w, :, 1] = view.ey[ego_rows]
    out["ego_vxy_mps"][w, :, 0] = view.sx * arr.vx[view.sl][ego_rows]
    out["ego_vxy_mps"][w, :, 1] = view.sy * arr.vy[view.sl][ego_rows]
    out["ego_axy_mps2"][w, :, 0] = view.sx * arr.ax[view.sl][ego_rows]
    out["ego_axy_mps2"][w, :, 1] = view.sy * arr.ay[view.sl][ego_rows]
    out["ego_lane_id"][w] = arr.lane[view.sl][ego_rows]


def _store_track(out: dict[str, np.ndarray], prefix: str, w: int, j: int, vehicle: int, rows: np.ndarray,
                 t: np.ndarray, arr: _RecordingArrays, view: _WindowView) -> None:
    """Vehicle ``vehicle``'s class, size and track (its ``rows`` at time indices ``t``) into slot ``j``
    of window ``w``: ``prefix`` ``nbr`` (neighbours, with lane ids) or ``ctx`` (context vehicles)."""
    out[f"{prefix}_id"][w, j] = vehicle
    out[f"{prefix}_class"][w, j] = arr.vclass[vehicle]
    out[f"{prefix}_length_m"][w, j] = arr.length[vehicle]
    out[f"{prefix}_width_m"][w, j] = arr.width[vehicle]
    out[f"{prefix}_xy_m"][w, j, t, 0] = view.ex[rows]
    out[f"{prefix}_xy_m"][w, j, t, 1] = view.ey[rows]
    out[f"{prefix}_vxy_mps"][w, j, t, 0] = view.sx * arr.vx[view.sl][rows]
    out[f"{prefix}_vxy_mps"][w, j, t, 1] = view.sy * arr.vy[view.sl][rows]
    out[f"{prefix}_valid"][w, j, t] = True
    if f"{prefix}_lane_id" in out:
        out[f"{prefix}_lane_id"][w, j, t] = arr.lane[view.sl][rows]


def extract_windows(
    rec: Recording,
    ego_ids: np.ndarray,
    start_frames: np.ndarray,
    progress: Callable[[int], None] | None = None,
) -> ScenarioBatch:
    """Extract the given windows (shape (W,) each) of one recording into a ScenarioBatch."""
    arr = _RecordingArrays(rec)
    n_win = len(ego_ids)
    markings_m = max(len(rec.lower_markings_y_m), len(rec.upper_markings_y_m))
    out = _empty_batch_arrays(n_win, MAX_NEIGHBOURS, markings_m)
    speed_limit = float(rec.meta.get("speedLimit", -1.0))  # type: ignore[arg-type]
    rec_key = recording_key(rec)
    location = int(rec.meta.get("locationId", 0))  # type: ignore[call-overload]
    for w in range(n_win):
        ego, start = int(ego_ids[w]), int(start_frames[w])
        sl = arr.rows_of_frames(start, start + N_TOTAL - 1)
        fr = arr.frame[sl] - start  # window frame offset 0..199 per row
        vid = arr.vid[sl]
        is_ego = vid == ego
        if int(is_ego.sum()) != N_TOTAL:
            raise ValueError(
                f"recording {rec.recording_id}: vehicle {ego} is not present in all frames "
                f"{start}..{start + N_TOTAL - 1}"
            )
        direction = int(arr.direction[ego])
        ego_rows = np.flatnonzero(is_ego)  # frame-sorted, so one row per offset in order
        cx, cy = arr.cx[sl], arr.cy[sl]
        cx0, cy0 = cx[ego_rows[T0_INDEX]], cy[ego_rows[T0_INDEX]]
        ex, ey = _to_ego_frame(direction, cx, cy, cx0, cy0)
        view = _WindowView(sl, fr, vid, ex, ey, *_sign(direction))
        keep, ctx = _neighbours_and_context(arr, view, is_ego, ego_rows, direction)

        out["scenario_id"][w] = f"r{rec.recording_id:02d}_v{ego}_f{start + T0_INDEX}"
        out["recording_id"][w] = rec.recording_id
        out["recording_key"][w] = rec_key
        out["location_id"][w] = location
        out["ego_id"][w] = ego
        out["frame0"][w] = start + T0_INDEX
        out["driving_direction"][w] = direction
        out["speed_limit_mps"][w] = speed_limit if speed_limit > 0 else np.nan
        _store_ego(out, w, ego, ego_rows, arr, view)
        for j, nid in enumerate(keep):
            rows = np.flatnonzero(vid == nid)
            _store_track(out, "nbr", w, j, nid, rows, fr[rows], arr, view)
        for j, cid in enumerate(ctx):
            rows = np.flatnonzero((vid == cid) & (fr > T0_INDEX))
            _store_track(out, "ctx", w, j, cid, rows, fr[rows] - (T0_INDEX + 1), arr, view)
        my, edge, lane_ids = _road_arrays(rec, direction, cy0)
        out["marking_y_m"][w, : len(my)] = my
        out["marking_is_edge"][w, : len(my)] = edge
        out["lane_ids"][w, : len(lane_ids)] = lane_ids
        if progress is not None:
            progress(1)
    used = int((out["ctx_id"] != 0).sum(axis=1).max()) if n_win else 0
    for name in CONTEXT_FIELDS:  # drop context slots no window of this recording uses
        out[name] = out[name][:, :used]
    return ScenarioBatch(**out)


def _empty_batch_arrays(n_win: int, n: int, m: int) -> dict[str, np.ndarray]:
    f32, t = np.float32, N_TOTAL
    return {
        "scenario_id": np.empty(n_win, dtype=object),
        "recording_id": np.zeros(n_win, np.int32),
        "recording_key": np.empty(n_win, dtype=object),
        "location_id": np.zeros(n_win, np.int32),
        "ego_id": np.zeros(n_win, np.int32),
        "frame0": np.zeros(n_win, np.int32),
        "driving_direction": np.zeros(n_win, np.int8),
        "speed_limit_mps": np.full(n_win, np.nan, f32),
        "ego_class": np.zeros(n_win, np.int8),
        "ego_length_m": np.zeros(n_win, f32),
        "ego_width_m": np.zeros(n_win, f32),
        "ego_xy_m": np.zeros((n_win, t, 2), f32),
        "ego_vxy_mps": np.zeros((n_win, t, 2), f32),
        "ego_axy_mps2": np.zeros((n_win, t, 2), f32),
        "ego_lane_id": np.zeros((n_win, t), np.int8),
        **_empty_tracks("nbr", n_win, n, t),
        "nbr_lane_id": np.zeros((n_win, n, t), np.int8),
        "marking_y_m": np.full((n_win, m), np.nan, f32),
        "marking_is_edge": np.zeros((n_win, m), bool),
        "lane_ids": np.zeros((n_win, max(m - 1, 0)), np.int8),
        **_empty_tracks("ctx", n_win, MAX_CONTEXT, N_FUTURE),
    }


def _empty_tracks(prefix: str, n_win: int, slots: int, steps: int) -> dict[str, np.ndarray]:
    """Empty ``prefix``_* arrays of ``slots`` other vehicles over ``steps`` steps (no vehicle, NaN tracks)."""
    return {
        f"{prefix}_id": np.zeros((n_win, slots), np.int32),
        f"{prefix}_class": np.full((n_win, slots), VEHICLE_CLASS_NONE, np.int8),
        f"{prefix}_length_m": np.zeros((n_win, slots), np.float32),
        f"{prefix}_width_m": np.zeros((n_win, slots), np.float32),
        f"{prefix}_xy_m": np.full((n_win, slots, steps, 2), np.nan, np.float32),
        f"{prefix}_vxy_mps": np.full((n_win, slots, steps, 2), np.nan, np.float32),
        f"{prefix}_valid": np.zeros((n_win, slots, steps), bool),
    }


def extract_scenarios(
    recordings: Sequence[Recording],
    *,
    max_scenarios: int | None = None,
    seed: int = 0,
    stride_frames: int = DEFAULT_STRIDE_FRAMES,
    critical_share: float = 0.0,
    events: Mapping[int, pd.DataFrame | None] | None = None,
    progress: Callable[[int], None] | None = None,
) -> ScenarioBatch:
    """All windows of the recordings, or ``max_scenarios`` of them sampled by ``seed`` (``sample_windows``)."""
    every = enumerate_windows(recordings, stride_frames)
    critical = critical_windows(recordings, every, events) if critical_share > 0 else None
    windows = sample_windows(every, max_scenarios, seed, critical, critical_share)
    if len(windows) == 0:
        raise ValueError(
            f"no {N_TOTAL}-frame windows in {len(recordings)} recording(s): "
            "every vehicle is visible for fewer than 8 s"
        )
    by_id = {rec.recording_id: rec for rec in recordings}
    batches = []
    for rid in np.unique(windows.recording_id):
        sel = windows.recording_id == rid
        batches.append(extract_windows(by_id[int(rid)], windows.ego_id[sel], windows.start_frame[sel], progress))
    return concat_batches(batches)


def count_windows(recordings: Sequence[Recording], stride_frames: int = DEFAULT_STRIDE_FRAMES) -> int:
    return len(enumerate_windows(recordings, stride_frames))

