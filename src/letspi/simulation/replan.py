"""The planner's view at a replanning instant: a ScenarioBatch built from the simulated history.

At frame ``c`` of the scenario window (``T0_INDEX`` = the original t = 0) the replanning batch is
the source batch shifted in time by ``c - T0_INDEX`` frames and re-centred at the ego's simulated
box centre at ``c``. The ego frame is a translation (plus a fixed 180 degree turn) of the image axes,
so re-centring is a translation: every ``*_xy_m`` field and ``marking_y_m`` move with the ego;
velocities and accelerations are unchanged.

The batch is built generically from ``ScenarioBatch``'s dataclass fields, so fields added later are
carried along: a field with a frame axis (the first non-batch axis whose length is the batch's frame
count) is windowed, anything else is copied. Then the simulated states overwrite the history
frames of the ego and neighbour fields. Future frames are NaN / invalid / 0 for planners that must
not see them (``future="none"``), or the recorded log from ``c`` on (``future="log"``, for
``human`` and oracle modes), NaN beyond the end of the recording.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Literal

import numpy as np

from letspi.constants import T0_INDEX
from letspi.scenario.queries import OFF_ROAD, lane_index_of
from letspi.scenario.types import CONTEXT_FIELDS, ScenarioBatch

FuturePolicy = Literal["none", "log"]


@dataclass(frozen=True)
class SimulatedStates:
    """Simulated states of K scenarios, indexed by the source batch's frames (T of them).

    ego_xy_m, ego_vxy_mps, ego_axy_mps2: (K, T, 2) box centre / velocity / acceleration, ego frame
    of the source scenario. ego_lane_id: (K, T). nbr_xy_m, nbr_vxy_mps: (K, N, T, 2);
    nbr_valid: (K, N, T); nbr_lane_id: (K, N, T). Frames not simulated yet are NaN / False / 0.
    """

    ego_xy_m: np.ndarray
    ego_vxy_mps: np.ndarray
    ego_axy_mps2: np.ndarray
    ego_lane_id: np.ndarray
    nbr_xy_m: np.ndarray
    nbr_vxy_mps: np.ndarray
    nbr_valid: np.ndarray
    nbr_lane_id: np.ndarray


def _fill_value(arr: np.ndarray) -> object:
    if arr.dtype == bool:
        return False
    if np.issubdtype(arr.dtype, np.floating):
        return np.nan
    return 0


def frame_axis(arr: np.ndarray, n_frames: int) -> int | None:
    """The frame axis of a batch field (first non-batch axis of length ``n_frames``), or None."""
    for axis in range(1, arr.ndim):
        if arr.shape[axis] == n_frames:
            return axis
    return None


def _window(arr: np.ndarray, axis: int, shift: int) -> np.ndarray:
    """``out[..., i, ...] = arr[..., i + shift, ...]`` along ``axis``, filled outside the source."""
    out = np.full(arr.shape, _fill_value(arr), dtype=arr.dtype)
    n = arr.shape[axis]
    lo, hi = max(0, -shift), min(n, n - shift)
    if hi > lo:
        dst = [slice(None)] * arr.ndim
        src = [slice(None)] * arr.ndim
        dst[axis] = slice(lo, hi)
        src[axis] = slice(lo + shift, hi + shift)
        out[tuple(dst)] = arr[tuple(src)]
    return out


def lane_ids_from_y(marking_y_m: np.ndarray, lane_ids: np.ndarray, y_m: np.ndarray) -> np.ndarray:
    """HighD lane ids (0 off the road or unknown) of lateral positions y_m (K, ...) given markings (K, M)."""
    idx = lane_index_of(marking_y_m, y_m)
    flat = idx.reshape(idx.shape[0], -1)
    ids = np.take_along_axis(np.asarray(lane_ids, dtype=np.int64), np.clip(flat, 0, None), axis=1)
    return np.where(flat == OFF_ROAD, 0, ids).reshape(idx.shape).astype(np.int8)


def replanning_batch(
    source: ScenarioBatch, sim: SimulatedStates, frame: int, future: FuturePolicy = "none"
) -> tuple[ScenarioBatch, np.ndarray]:
    """The batch a planner sees at ``frame`` (>= ``T0_INDEX``) and the re-centring offset.

    Returns ``(batch, centre_xy_m)``: ``centre_xy_m`` (K, 2) is the ego's simulated centre at
    ``frame`` in the source ego frame; add it to a plan's positions to bring them back.
    """
    n_frames = source.ego_xy_m.shape[1]
    if not T0_INDEX <= frame < n_frames:
        raise ValueError(f"replanning frame {frame} outside [{T0_INDEX}, {n_frames})")
    if future not in ("none", "log"):
        raise ValueError(f"future must be 'none' or 'log', got {future!r}")
    shift = frame - T0_INDEX
    hist = slice(0, T0_INDEX + 1)
    src_hist = slice(shift, frame + 1)
    centre = sim.ego_xy_m[:, frame].astype(np.float64)
    if not np.isfinite(centre).all():
        raise ValueError(f"the simulated ego position at frame {frame} is not finite")

    own = {
        "ego_xy_m": sim.ego_xy_m,
        "ego_vxy_mps": sim.ego_vxy_mps,
        "ego_axy_mps2": sim.ego_axy_mps2,
        "ego_lane_id": sim.ego_lane_id,
        "nbr_xy_m": sim.nbr_xy_m,
        "nbr_vxy_mps": sim.nbr_vxy_mps,
        "nbr_valid": sim.nbr_valid,
        "nbr_lane_id": sim.nbr_lane_id,
    }
    out: dict[str, np.ndarray] = {}
    for f in fields(ScenarioBatch):
        arr = np.asarray(getattr(source, f.name))
        axis = frame_axis(arr, n_frames)
        if axis is None:
            out[f.name] = arr.copy()
            continue
        win = _window(arr, axis, shift)
        index = [slice(None)] * arr.ndim
        if future == "none":
            index[axis] = slice(T0_INDEX + 1, n_frames)
            win[tuple(index)] = _fill_value(arr)
        if f.name in own:
            index[axis] = hist
            src_index = [slice(None)] * arr.ndim
            src_index[axis] = src_hist
            win[tuple(index)] = own[f.name][tuple(src_index)].astype(arr.dtype)
        out[f.name] = win

    # re-centre: positions move with the ego, markings with its y
    for name, arr in out.items():
        if name.endswith("_xy_m"):
            shape = (len(centre),) + (1,) * (arr.ndim - 2) + (2,)
            out[name] = (arr.astype(np.float64) - centre.reshape(shape)).astype(arr.dtype)
    out["marking_y_m"] = (out["marking_y_m"].astype(np.float64) - centre[:, 1:2]).astype(source.marking_y_m.dtype)
    out["frame0"] = (np.asarray(source.frame0) + shift).astype(source.frame0.dtype)
    if future == "none":  # context vehicles are future-only ground truth: never part of a planner's view
        out.update({name: out[name][:, :0] for name in CONTEXT_FIELDS})
    return ScenarioBatch(**out), centre
