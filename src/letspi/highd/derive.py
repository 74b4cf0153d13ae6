"""Build a complete HighD ``Recording`` from raw per-frame vehicle states, vectorised over all rows.

Where HighD leaves a definition open, letspi chooses:

- ``s`` = progress along the travel direction (``+x`` for drivingDirection 2, ``-x`` for 1); ahead = larger ``s``.
- ``laneId`` = 1 + number of markings (both carriageways) above the box centre, the markings rounded to the
  2 decimals of ``NN_recordingMeta.csv`` so that a reader recomputes the same lanes.
- ``precedingId``/``followingId``: nearest box centre ahead/behind in the same lane and direction (0 = none).
- left/right are relative to travel (direction 2: left = laneId - 1); in that lane *alongside* = overlapping
  along x (the one reaching furthest ahead), *preceding*/*following* = nearest one entirely ahead/behind.
- ``dhw`` [m] is the **bumper-to-bumper gap** (negative when boxes overlap, 0 without a preceding vehicle);
  ``thw`` = dhw / |xVelocity|; ``ttc`` = dhw / closing speed when closing and dhw > 0, else 0 (HighD's missing).
- tracksMeta's minima are over the frames where the value is defined (-1 when never); its speeds are of
  ``|xVelocity|``; sight distances are to the ends of the section ``[min(x), max(x + width)]``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from letspi.conflict import time_to_collision_s
from letspi.highd.schema import (
    DRIVING_DIRECTION_LOWER,
    DRIVING_DIRECTION_UPPER,
    TRACKS_COLUMNS,
    TRACKS_META_COLUMNS,
    VEHICLE_CLASSES,
)
from letspi.highd.types import Recording, format_markings, parse_markings

__all__ = ["STATE_COLUMNS", "VEHICLE_COLUMNS", "build_recording"]

STATE_COLUMNS: tuple[str, ...] = (
    "frame",
    "id",
    "x",
    "y",
    "width",
    "height",
    "xVelocity",
    "yVelocity",
    "xAcceleration",
    "yAcceleration",
)
VEHICLE_COLUMNS: tuple[str, ...] = ("id", "class", "drivingDirection")


def _check_inputs(states: pd.DataFrame, vehicles: pd.DataFrame) -> None:
    for name, frame, cols in (("states", states, STATE_COLUMNS), ("vehicles", vehicles, VEHICLE_COLUMNS)):
        missing = [c for c in cols if c not in frame.columns]
        if missing:
            raise ValueError(f"{name} is missing columns {missing}")
    if len(states) == 0:
        raise ValueError("states is empty")
    if (vehicles["id"] <= 0).any():
        raise ValueError("vehicle ids must be positive (0 means 'no vehicle' in HighD)")
    if vehicles["id"].duplicated().any():
        raise ValueError("vehicles has duplicated ids")
    bad_class = ~vehicles["class"].isin(VEHICLE_CLASSES)
    if bad_class.any():
        raise ValueError(f"unknown vehicle class {vehicles['class'][bad_class].iloc[0]!r}")
    bad_dir = ~vehicles["drivingDirection"].isin([DRIVING_DIRECTION_UPPER, DRIVING_DIRECTION_LOWER])
    if bad_dir.any():
        raise ValueError("drivingDirection must be 1 or 2")
    unknown = ~states["id"].isin(vehicles["id"])
    if unknown.any():
        raise ValueError(f"states contains vehicle id {states['id'][unknown].iloc[0]} not in vehicles")
    if not np.isfinite(states[list(STATE_COLUMNS)].to_numpy(dtype=np.float64)).all():
        raise ValueError("states contains NaN or infinite values")


def _neighbour_ids(
    group: np.ndarray, s_centre: np.ndarray, ids: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Nearest neighbours ahead/behind along ``s`` within a group. ``group`` (N,) int64 key (frame, direction, lane),
    ``s_centre`` (N,) [m], ``ids`` (N,). Returns the preceding and following ids (0 = none) and row indices (-1 = none),
    (N,) each."""
    n = len(ids)
    order = np.lexsort((s_centre, group))
    same_next = group[order[1:]] == group[order[:-1]]
    behind_rows, ahead_rows = order[:-1][same_next], order[1:][same_next]
    prec_row = np.full(n, -1, dtype=np.int64)
    foll_row = np.full(n, -1, dtype=np.int64)
    prec_row[behind_rows] = ahead_rows
    foll_row[ahead_rows] = behind_rows
    prec_id = np.where(prec_row >= 0, ids[prec_row], 0)
    foll_id = np.where(foll_row >= 0, ids[foll_row], 0)
    return prec_id, foll_id, prec_row, foll_row


def _asof(
    query_key: np.ndarray,
    query_s: np.ndarray,
    target_key: np.ndarray,
    target_s: np.ndarray,
    target_values: dict[str, np.ndarray],
    *,
    direction: str,
    allow_exact_matches: bool,
) -> dict[str, np.ndarray]:
    """Per query (Q,), the target (T,) values asof-matched on ``s`` in the same key: (Q,) float64, NaN if none."""
    left = pd.DataFrame({"key": query_key, "s": query_s, "q": np.arange(len(query_key))})
    right = pd.DataFrame({"key": target_key, "s": target_s, **target_values})
    merged = pd.merge_asof(
        left.sort_values("s", kind="stable"),
        right.sort_values("s", kind="stable"),
        on="s",
        by="key",
        direction=direction,  # type: ignore[arg-type]
        allow_exact_matches=allow_exact_matches,
    )
    rows = merged["q"].to_numpy()
    out: dict[str, np.ndarray] = {}
    for name in target_values:
        col = np.full(len(query_key), np.nan)
        col[rows] = merged[name].to_numpy(dtype=np.float64)
        out[name] = col
    return out


def _group_key(frame: np.ndarray, direction: np.ndarray, lane: np.ndarray) -> np.ndarray:
    # adjacent-lane queries can reach lane 0; the offset keeps the packed key unique and positive
    lane_code = lane.astype(np.int64) + 512
    return (frame.astype(np.int64) * 4 + direction.astype(np.int64)) * 1024 + lane_code


def build_recording(states: pd.DataFrame, vehicles: pd.DataFrame, *, recording_id: int,
                    upper_markings_y_m: Sequence[float], lower_markings_y_m: Sequence[float], frame_rate_hz: int = 25,
                    location_id: int = 0, speed_limit_mps: float = -1.0, month: str = "01", week_day: str = "Mon",
                    start_time: str = "08:00") -> Recording:
    """Compute all derived HighD columns and return a complete, valid ``Recording`` (tracks sorted by (id, frame)).

    Args:
        states: one row per vehicle per frame: ``frame`` (consecutive per vehicle), ``id`` (> 0), ``x, y`` [m]
            (top-left box corner, image axes, y down), ``width`` [m] (vehicle length), ``height`` [m] (its width),
            ``xVelocity, yVelocity`` [m/s], ``xAcceleration, yAcceleration`` [m/s²].
        vehicles: one row per vehicle: ``id``, ``class`` ("Car"/"Truck"), ``drivingDirection`` (1 = towards -x on
            the upper lanes, 2 = towards +x on the lower lanes).
        upper_markings_y_m, lower_markings_y_m: image y [m] of each carriageway's markings, road edges included.
        The other keywords are copied into recordingMeta (``speed_limit_mps`` -1 = none).

    Raises ValueError on missing columns, unknown ids/classes/directions, non-finite values or non-consecutive frames.
    """
    _check_inputs(states, vehicles)
    veh = vehicles.set_index("id")
    # lanes from the markings as they will be stored (2 decimals), see module docstring
    upper_text = format_markings(np.asarray(upper_markings_y_m, dtype=np.float64))
    lower_text = format_markings(np.asarray(lower_markings_y_m, dtype=np.float64))
    markings = np.sort(np.concatenate([parse_markings(upper_text), parse_markings(lower_text)]))
    tracks, has_prec, ttc_ok = _tracks(_sorted_states(states), veh, markings)
    tracks_meta = _tracks_meta(tracks, veh, has_prec, ttc_ok)
    meta: dict[str, object] = {
        "id": int(recording_id), "frameRate": int(frame_rate_hz), "locationId": int(location_id),
        "speedLimit": float(speed_limit_mps), "month": str(month), "weekDay": str(week_day),
        "startTime": str(start_time), **_totals(tracks["frame"].to_numpy(), tracks_meta, frame_rate_hz),
        "upperLaneMarkings": upper_text, "lowerLaneMarkings": lower_text,
    }
    return Recording(recording_id=int(recording_id), meta=meta, tracks_meta=tracks_meta, tracks=tracks)


def _tracks(st: pd.DataFrame, veh: pd.DataFrame, markings: np.ndarray) -> tuple[pd.DataFrame, np.ndarray, np.ndarray]:
    """The tracks table of states sorted by (id, frame), and the (N,) masks where a preceding vehicle exists and where
    TTC is defined."""
    ids = st["id"].to_numpy(dtype=np.int64)
    frames = st["frame"].to_numpy(dtype=np.int64)
    x, y, length, width_m = (st[c].to_numpy(dtype=np.float64) for c in ("x", "y", "width", "height"))
    vx = st["xVelocity"].to_numpy(dtype=np.float64)
    direction = st["id"].map(veh["drivingDirection"]).to_numpy(dtype=np.int64)
    lane = 1 + np.searchsorted(markings, y + width_m / 2.0, side="left").astype(np.int64)
    # progress coordinate along the travel direction: everything below is "ahead = larger s"
    sign = np.where(direction == DRIVING_DIRECTION_LOWER, 1.0, -1.0)
    s_centre = sign * (x + length / 2.0)
    key = _group_key(frames, direction, lane)
    leader = _leader_columns(key, s_centre, length, sign * vx, vx, ids)
    tracks = pd.DataFrame(
        {
            "frame": frames,
            "id": ids,
            "x": x,
            "y": y,
            "width": length,
            "height": width_m,
            "xVelocity": vx,
            "yVelocity": st["yVelocity"].to_numpy(dtype=np.float64),
            "xAcceleration": st["xAcceleration"].to_numpy(dtype=np.float64),
            "yAcceleration": st["yAcceleration"].to_numpy(dtype=np.float64),
            **_sight_distances(x, length, direction),
            **{k: v for k, v in leader.items() if not k.startswith("_")},
            **_adjacent_columns(frames, direction, lane, key, s_centre, length, ids),
            "laneId": lane,
        }
    )[list(TRACKS_COLUMNS)]
    return tracks, leader["_has_preceding"], leader["_ttc_defined"]


def _sorted_states(states: pd.DataFrame) -> pd.DataFrame:
    """The state columns sorted by (id, frame); ``ValueError`` unless each vehicle's frames are consecutive."""
    st = states[list(STATE_COLUMNS)].sort_values(["id", "frame"], kind="stable").reset_index(drop=True)
    ids = st["id"].to_numpy(dtype=np.int64)
    frames = st["frame"].to_numpy(dtype=np.int64)
    if np.any((ids[1:] == ids[:-1]) & (np.diff(frames) != 1)):
        raise ValueError("frames of each vehicle must be consecutive and unique")
    return st


def _leader_columns(key: np.ndarray, s_centre: np.ndarray, length: np.ndarray, v_s: np.ndarray, vx: np.ndarray,
                    ids: np.ndarray) -> dict[str, np.ndarray]:
    """Same-lane neighbour columns (N,): preceding/following ids, dhw [m], thw [s], ttc [s] (0 where
    undefined, as highD writes them), preceding x velocity; and, prefixed ``_``, the masks where the
    preceding vehicle exists and where TTC is defined (for the per-vehicle minima)."""
    s_front, s_rear = s_centre + length / 2.0, s_centre - length / 2.0
    prec_id, foll_id, prec_row, _ = _neighbour_ids(key, s_centre, ids)
    has_prec = prec_row >= 0
    pr = np.where(has_prec, prec_row, 0)
    dhw = np.where(has_prec, s_rear[pr] - s_front, 0.0)
    speed = np.abs(vx)
    closing = v_s - v_s[pr]
    return {
        "dhw": dhw,
        "thw": np.where(has_prec & (speed > 0), dhw / np.where(speed > 0, speed, 1.0), 0.0),
        "ttc": np.where(has_prec, time_to_collision_s(dhw, closing, contact_s=0.0, not_closing_s=0.0), 0.0),
        "precedingXVelocity": np.where(has_prec, vx[pr], 0.0),
        "precedingId": prec_id,
        "followingId": foll_id,
        "_has_preceding": has_prec,
        "_ttc_defined": has_prec & (closing > 0) & (dhw > 0),
    }


def _adjacent_columns(frames: np.ndarray, direction: np.ndarray, lane: np.ndarray, key: np.ndarray,
                      s_centre: np.ndarray, length: np.ndarray, ids: np.ndarray) -> dict[str, np.ndarray]:
    """Ids (0 = none) of the preceding, alongside and following vehicle in the left and right lanes,
    (N,) each. Left = towards the median (lane - 1 for direction 2, lane + 1 for direction 1)."""
    s_front, s_rear = s_centre + length / 2.0, s_centre - length / 2.0
    left_step = np.where(direction == DRIVING_DIRECTION_LOWER, -1, 1)
    n = len(ids)
    q_key = np.concatenate(
        [_group_key(frames, direction, lane + left_step), _group_key(frames, direction, lane - left_step)]
    )
    q_front = np.concatenate([s_front, s_front])
    q_rear = np.concatenate([s_rear, s_rear])
    id_f = ids.astype(np.float64)
    ahead = _asof(q_key, q_front, key, s_rear, {"id": id_f}, direction="forward", allow_exact_matches=True)["id"]
    behind = _asof(q_key, q_rear, key, s_front, {"id": id_f}, direction="backward", allow_exact_matches=True)["id"]
    # the last target starting before the ego front is the only candidate for overlap (vehicles in
    # one lane do not overlap each other): alongside iff its front is beyond the ego rear
    last = _asof(
        q_key, q_front, key, s_rear, {"id": id_f, "front": s_front}, direction="backward", allow_exact_matches=False
    )
    alongside = np.where(last["front"] > q_rear, last["id"], np.nan)
    ahead_i, along_i, behind_i = (np.nan_to_num(v, nan=0.0).astype(np.int64) for v in (ahead, alongside, behind))
    return {
        "leftPrecedingId": ahead_i[:n],
        "leftAlongsideId": along_i[:n],
        "leftFollowingId": behind_i[:n],
        "rightPrecedingId": ahead_i[n:],
        "rightAlongsideId": along_i[n:],
        "rightFollowingId": behind_i[n:],
    }


def _sight_distances(x: np.ndarray, length: np.ndarray, direction: np.ndarray) -> dict[str, np.ndarray]:
    """Distance [m] from each box to the recorded window's edge ahead of and behind it, (N,) each."""
    x_min = float(x.min())
    x_max = float((x + length).max())
    return {
        "frontSightDistance": np.where(direction == DRIVING_DIRECTION_LOWER, x_max - (x + length), x - x_min),
        "backSightDistance": np.where(direction == DRIVING_DIRECTION_LOWER, x - x_min, x_max - (x + length)),
    }


def _totals(frames: np.ndarray, tracks_meta: pd.DataFrame, frame_rate_hz: int) -> dict[str, object]:
    """recordingMeta's duration and totals."""
    return {
        "duration": float(frames.max() - frames.min() + 1) / frame_rate_hz,
        "totalDrivenDistance": float(tracks_meta["traveledDistance"].sum()),
        "totalDrivenTime": float(tracks_meta["numFrames"].sum()) / frame_rate_hz,
        "numVehicles": len(tracks_meta),
        "numCars": int((tracks_meta["class"] == "Car").sum()),
        "numTrucks": int((tracks_meta["class"] == "Truck").sum()),
    }


def _tracks_meta(tracks: pd.DataFrame, veh: pd.DataFrame, has_prec: np.ndarray, ttc_ok: np.ndarray) -> pd.DataFrame:
    """Per-vehicle summary. ``tracks`` sorted by (id, frame); masks have shape (N,)."""
    ids = tracks["id"].to_numpy()
    same = np.r_[False, ids[1:] == ids[:-1]]
    cx = tracks["x"].to_numpy() + tracks["width"].to_numpy() / 2.0
    cy = tracks["y"].to_numpy() + tracks["height"].to_numpy() / 2.0
    step = np.where(same, np.hypot(np.diff(cx, prepend=cx[0]), np.diff(cy, prepend=cy[0])), 0.0)
    lane = tracks["laneId"].to_numpy()
    lane_change = same & (np.diff(lane, prepend=lane[0]) != 0)
    speed = np.abs(tracks["xVelocity"].to_numpy())
    work = pd.DataFrame(
        {
            "id": ids,
            "width": tracks["width"].to_numpy(),
            "height": tracks["height"].to_numpy(),
            "frame": tracks["frame"].to_numpy(),
            "step": step,
            "speed": speed,
            "dhw": np.where(has_prec, tracks["dhw"].to_numpy(), np.nan),
            "thw": np.where(has_prec & (speed > 0), tracks["thw"].to_numpy(), np.nan),
            "ttc": np.where(ttc_ok, tracks["ttc"].to_numpy(), np.nan),
            "lc": lane_change.astype(np.int64),
        }
    )
    g = work.groupby("id", sort=True)
    agg = g.agg(
        width=("width", "first"),
        height=("height", "first"),
        initialFrame=("frame", "min"),
        finalFrame=("frame", "max"),
        numFrames=("frame", "size"),
        traveledDistance=("step", "sum"),
        minXVelocity=("speed", "min"),
        maxXVelocity=("speed", "max"),
        meanXVelocity=("speed", "mean"),
        minDHW=("dhw", "min"),
        minTHW=("thw", "min"),
        minTTC=("ttc", "min"),
        numLaneChanges=("lc", "sum"),
    )
    agg[["minDHW", "minTHW", "minTTC"]] = agg[["minDHW", "minTHW", "minTTC"]].fillna(-1.0)
    agg["class"] = veh.loc[agg.index, "class"].astype(str).to_numpy()
    agg["drivingDirection"] = veh.loc[agg.index, "drivingDirection"].to_numpy(dtype=np.int64)
    out = agg.reset_index()
    for col in ("id", "initialFrame", "finalFrame", "numFrames", "numLaneChanges"):
        out[col] = out[col].astype(np.int64)
    return out[list(TRACKS_META_COLUMNS)]
