"""Questions about scenarios that planners, metrics and prompts ask (vectorised over the batch).

Relations use the ego-frame lanes (index between markings, 0 = rightmost, from the centre y): ``preceding`` /
``following``: same lane, nearest ahead/behind by centre x; ``left``/``right``: the adjacent lane, nearest by |Δx|.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from letspi.scenario.types import ScenarioBatch

Relation = Literal["preceding", "following", "left", "right"]
RELATIONS: tuple[Relation, ...] = ("preceding", "following", "left", "right")
OFF_ROAD = -1


def lane_index_of(marking_y_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
    """Lane index (0 = rightmost) of lateral positions ``y_m`` (B, ...), ``OFF_ROAD`` (-1) outside the road edges;
    ``marking_y_m`` (B, M) ascending, NaN padded at the end. Returns ints shaped like ``y_m``."""
    marking = np.asarray(marking_y_m, dtype=np.float64)
    y = np.asarray(y_m, dtype=np.float64)
    b = marking.shape[0]
    flat = y.reshape(b, -1)
    # count markings strictly below y; NaN padding compares False, so it is never counted
    below = (marking[:, None, :] < flat[:, :, None]).sum(axis=-1)
    n_markings = np.sum(~np.isnan(marking), axis=1)[:, None]
    lane = below - 1
    lane = np.where((below == 0) | (below >= n_markings) | np.isnan(flat), OFF_ROAD, lane)
    return lane.reshape(y.shape)


def lane_id_of(batch: ScenarioBatch, y_m: np.ndarray) -> np.ndarray:
    """HighD laneId of lateral positions ``y_m`` (B, ...); 0 when off the road."""
    idx = lane_index_of(batch.marking_y_m, y_m)
    b = len(batch)
    flat = idx.reshape(b, -1)
    ids = np.take_along_axis(batch.lane_ids.astype(np.int64), np.clip(flat, 0, None), axis=1)
    return np.where(flat == OFF_ROAD, 0, ids).reshape(idx.shape)


def lane_centres_y_m(batch: ScenarioBatch) -> np.ndarray:
    """Lane centre lines (B, M - 1), ascending, NaN padded."""
    m = batch.marking_y_m.astype(np.float64)
    return 0.5 * (m[:, :-1] + m[:, 1:])


def neighbour_at(batch: ScenarioBatch, frame_index: int, relation: Relation) -> np.ndarray:
    """Slot of the ego's ``relation`` neighbour at ``frame_index``, or -1 if there is none. Shape (B,)."""
    if relation not in RELATIONS:
        raise ValueError(f"relation must be one of {RELATIONS}, got {relation!r}")
    ego_y = batch.ego_xy_m[:, frame_index, 1]
    ego_x = batch.ego_xy_m[:, frame_index, 0]
    nbr_xy = batch.nbr_xy_m[:, :, frame_index].astype(np.float64)  # (B, N, 2)
    valid = batch.nbr_valid[:, :, frame_index]
    ego_lane = lane_index_of(batch.marking_y_m, ego_y[:, None])  # (B, 1)
    nbr_lane = lane_index_of(batch.marking_y_m, nbr_xy[..., 1])  # (B, N)
    dx = nbr_xy[..., 0] - ego_x[:, None].astype(np.float64)
    if relation == "preceding":
        ok = valid & (nbr_lane == ego_lane) & (dx > 0)
        key = dx
    elif relation == "following":
        ok = valid & (nbr_lane == ego_lane) & (dx <= 0)
        key = -dx
    else:
        target = ego_lane + (1 if relation == "left" else -1)
        ok = valid & (nbr_lane == target) & (ego_lane != OFF_ROAD)
        key = np.abs(dx)
    key = np.where(ok, key, np.inf)
    slot = np.argmin(key, axis=1)
    return np.where(np.isfinite(key[np.arange(len(slot)), slot]), slot, -1)
