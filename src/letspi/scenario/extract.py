"""HighD recordings → ego-centric planning scenarios (paper §IV-B).

Every vehicle with at least ``N_TOTAL`` frames yields windows of ``N_TOTAL`` frames starting at its
first frame and then every ``stride_frames`` frames. In each window:

* the ego's states are transformed into the ego frame (see ``letspi.scenario.types``);
* neighbours are the other vehicles **of the same driving direction** whose centre comes within
  ``NEIGHBOUR_RADIUS_M`` of the ego's centre at any frame of the window (both present); the
  ``MAX_NEIGHBOURS`` closest by that minimum distance are kept, closest first (distances compared
  at 1 mm resolution; ties: lower id).
  Opposite-carriageway traffic is separated by the median and never interacts, so it is left out.
  Note the selection looks at the whole 8 s window, like the paper; planners must only read
  neighbour states at frames ``<= T0_INDEX`` (``nbr_valid`` tells which slots have a history).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from letspi.constants import (
    DEFAULT_STRIDE_FRAMES,
    MAX_NEIGHBOURS,
    N_TOTAL,
    NEIGHBOUR_RADIUS_M,
    T0_INDEX,
)
from letspi.highd.schema import DRIVING_DIRECTION_LOWER
from letspi.highd.types import Recording
from letspi.scenario.types import (
    VEHICLE_CLASS_CAR,
    VEHICLE_CLASS_NONE,
    VEHICLE_CLASS_TRUCK,
    ScenarioBatch,
    concat_batches,
)

_CLASS_CODES = {"Car": VEHICLE_CLASS_CAR, "Truck": VEHICLE_CLASS_TRUCK}


@dataclass(frozen=True)
class WindowIndex:
    """Which windows exist, before any are extracted. All arrays have shape (W,).

    ``start_frame`` is the HighD frame of the window's first frame; t = 0 is
    ``start_frame + T0_INDEX``.
    """

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


def sample_windows(windows: WindowIndex, max_n: int | None, seed: int) -> WindowIndex:
    """Up to ``max_n`` windows drawn uniformly without replacement, reproducible by ``seed``.

    The result is sorted by (recording, ego, start) so extraction reads each recording once.
    """
    n = len(windows)
    if max_n is None or max_n >= n:
        chosen = np.arange(n)
    else:
        chosen = np.sort(np.random.default_rng(seed).choice(n, size=max_n, replace=False))
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
    """A short content hash of a recording (its meta and every vehicle's meta row): the same
    recording gives the same key wherever it is read from, another recording another key."""
    h = hashlib.blake2b(digest_size=8)
    h.update(repr(sorted((str(k), str(v)) for k, v in rec.meta.items())).encode())
    h.update(pd.util.hash_pandas_object(rec.tracks_meta, index=False).to_numpy().tobytes())
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


def extract_windows(
    rec: Recording,
    ego_ids: np.ndarray,
    start_frames: np.ndarray,
    progress: Callable[[int], None] | None = None,
) -> ScenarioBatch:
    """Extract the given windows (shape (W,) each) of one recording into a ScenarioBatch."""
    arr = _RecordingArrays(rec)
    n_win = len(ego_ids)
    n = MAX_NEIGHBOURS
    markings_m = len(rec.lower_markings_y_m)
    markings_m = max(markings_m, len(rec.upper_markings_y_m))
    out = _empty_batch_arrays(n_win, n, markings_m)
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
        sx, sy = _sign(direction)

        # neighbour candidates: same direction, within the radius at some frame
        ego_x_at, ego_y_at = ex[ego_rows], ey[ego_rows]
        dist = np.hypot(ex - ego_x_at[fr], ey - ego_y_at[fr])
        cand = (~is_ego) & (arr.direction[vid] == direction) & (dist <= NEIGHBOUR_RADIUS_M)
        cand_ids = vid[cand]
        if len(cand_ids):
            uniq, inv = np.unique(cand_ids, return_inverse=True)
            min_d = np.full(len(uniq), np.inf)
            np.minimum.at(min_d, inv, dist[cand])
            # rank at 1 mm resolution so float noise from CSV round trips can't reorder ties
            keep = uniq[np.lexsort((uniq, np.round(min_d, 3)))][:n]
        else:
            keep = np.zeros(0, dtype=np.int64)

        out["scenario_id"][w] = f"r{rec.recording_id:02d}_v{ego}_f{start + T0_INDEX}"
        out["recording_id"][w] = rec.recording_id
        out["recording_key"][w] = rec_key
        out["location_id"][w] = location
        out["ego_id"][w] = ego
        out["frame0"][w] = start + T0_INDEX
        out["driving_direction"][w] = direction
        out["speed_limit_mps"][w] = speed_limit if speed_limit > 0 else np.nan
        out["ego_class"][w] = arr.vclass[ego]
        out["ego_length_m"][w] = arr.length[ego]
        out["ego_width_m"][w] = arr.width[ego]
        out["ego_xy_m"][w, :, 0] = ego_x_at
        out["ego_xy_m"][w, :, 1] = ego_y_at
        out["ego_vxy_mps"][w, :, 0] = sx * arr.vx[sl][ego_rows]
        out["ego_vxy_mps"][w, :, 1] = sy * arr.vy[sl][ego_rows]
        out["ego_axy_mps2"][w, :, 0] = sx * arr.ax[sl][ego_rows]
        out["ego_axy_mps2"][w, :, 1] = sy * arr.ay[sl][ego_rows]
        out["ego_lane_id"][w] = arr.lane[sl][ego_rows]
        for j, nid in enumerate(keep):
            rows = np.flatnonzero(vid == nid)
            t = fr[rows]
            out["nbr_id"][w, j] = nid
            out["nbr_class"][w, j] = arr.vclass[nid]
            out["nbr_length_m"][w, j] = arr.length[nid]
            out["nbr_width_m"][w, j] = arr.width[nid]
            out["nbr_xy_m"][w, j, t, 0] = ex[rows]
            out["nbr_xy_m"][w, j, t, 1] = ey[rows]
            out["nbr_vxy_mps"][w, j, t, 0] = sx * arr.vx[sl][rows]
            out["nbr_vxy_mps"][w, j, t, 1] = sy * arr.vy[sl][rows]
            out["nbr_valid"][w, j, t] = True
            out["nbr_lane_id"][w, j, t] = arr.lane[sl][rows]
        my, edge, lane_ids = _road_arrays(rec, direction, cy0)
        out["marking_y_m"][w, : len(my)] = my
        out["marking_is_edge"][w, : len(my)] = edge
        out["lane_ids"][w, : len(lane_ids)] = lane_ids
        if progress is not None:
            progress(1)
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
        "nbr_id": np.zeros((n_win, n), np.int32),
        "nbr_class": np.full((n_win, n), VEHICLE_CLASS_NONE, np.int8),
        "nbr_length_m": np.zeros((n_win, n), f32),
        "nbr_width_m": np.zeros((n_win, n), f32),
        "nbr_xy_m": np.full((n_win, n, t, 2), np.nan, f32),
        "nbr_vxy_mps": np.full((n_win, n, t, 2), np.nan, f32),
        "nbr_valid": np.zeros((n_win, n, t), bool),
        "nbr_lane_id": np.zeros((n_win, n, t), np.int8),
        "marking_y_m": np.full((n_win, m), np.nan, f32),
        "marking_is_edge": np.zeros((n_win, m), bool),
        "lane_ids": np.zeros((n_win, max(m - 1, 0)), np.int8),
    }


def extract_scenarios(
    recordings: Sequence[Recording],
    *,
    max_scenarios: int | None = None,
    seed: int = 0,
    stride_frames: int = DEFAULT_STRIDE_FRAMES,
    progress: Callable[[int], None] | None = None,
) -> ScenarioBatch:
    """All windows of the recordings, or ``max_scenarios`` of them sampled reproducibly by ``seed``."""
    windows = sample_windows(enumerate_windows(recordings, stride_frames), max_scenarios, seed)
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

