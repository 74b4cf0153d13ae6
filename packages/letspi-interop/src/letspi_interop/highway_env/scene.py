"""An episode's road and recorded states, as letspi scenarios and as a HighD recording (NumPy only).

highway-env's world (x along the road, y to the right of travel, lane 0 leftmost, box centres, metres) is
HighD's image frame of driving direction 2 up to a shift of y. ``scenario_view`` builds an ego-centric
scenario as ``letspi.scenario.extract`` does from a direction-2 recording (history interpolated to 25 Hz,
back-filled at constant velocity before the first frame); ``episode_recording`` writes the road as HighD's
lower carriageway (``RoadLayout``). Only straight roads along x (``highway-v0``, ``merge-v0``'s main
carriageway). Details: notes/rationale-runtime-evaluation.md, "highway-env frames".
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import pandas as pd

from letspi.constants import DT_S, FRAME_RATE_HZ, MAX_NEIGHBOURS, N_FUTURE, N_HISTORY, NEIGHBOUR_RADIUS_M, T0_INDEX
from letspi.highd.derive import build_recording
from letspi.highd.schema import DRIVING_DIRECTION_LOWER
from letspi.highd.types import Recording
from letspi.scenario.types import VEHICLE_CLASS_CAR, VEHICLE_CLASS_NONE, ScenarioBatch

#: image y of the upper (empty) carriageway's first marking [m]
UPPER_MARGIN_M: Final = 2.0
#: gap between the upper carriageway's last marking and the lower one's first [m]
MEDIAN_M: Final = 3.0
#: a vehicle longer than this is a truck in HighD's classes [m]
TRUCK_LENGTH_M: Final = 7.0


@dataclass(frozen=True)
class RoadLayout:
    """The straight carriageway of an episode, in highway-env's y (to the right of travel).

    markings_y_m: (L + 1,) ascending; lane k (0 = leftmost) lies between markings k and k + 1; the outer two
    are the road edges. speed_limit_mps: the lanes' limit (NaN: none).
    """

    markings_y_m: np.ndarray
    speed_limit_mps: float

    def __post_init__(self) -> None:
        m = np.asarray(self.markings_y_m, dtype=np.float64)
        if m.ndim != 1 or len(m) < 2 or not np.isfinite(m).all() or (np.diff(m) <= 0).any():
            raise ValueError(f"a road needs at least two ascending finite markings, got {self.markings_y_m!r}")
        object.__setattr__(self, "markings_y_m", m)

    @property
    def n_lanes(self) -> int:
        return len(self.markings_y_m) - 1

    @property
    def upper_markings_image_m(self) -> np.ndarray:
        """(L + 1,) image y of the empty upper carriageway's markings (the same lanes, mirrored above)."""
        return UPPER_MARGIN_M + (self.markings_y_m - self.markings_y_m[0])

    @property
    def image_shift_m(self) -> float:
        """Image y = highway-env y + this shift (the road is HighD's lower carriageway)."""
        return float(self.upper_markings_image_m[-1] + MEDIAN_M - self.markings_y_m[0])

    @property
    def lower_markings_image_m(self) -> np.ndarray:
        return self.markings_y_m + self.image_shift_m

    def highd_lane_id(self, y_m: np.ndarray) -> np.ndarray:
        """HighD laneId (int8) of highway-env lateral positions: 1 + the markings of both carriageways above."""
        every = np.concatenate([self.upper_markings_image_m, self.lower_markings_image_m])
        image_y = np.asarray(y_m, dtype=np.float64) + self.image_shift_m
        return (1 + (every[None, :] < image_y.reshape(-1, 1)).sum(axis=1)).reshape(np.shape(y_m)).astype(np.int8)

    @property
    def lane_ids(self) -> np.ndarray:
        """(L,) HighD laneId of highway-env lane k (k = 0 leftmost)."""
        return self.highd_lane_id(0.5 * (self.markings_y_m[:-1] + self.markings_y_m[1:]))

    def lane_index(self, y_m: np.ndarray) -> np.ndarray:
        """highway-env lane index (0 = leftmost) of lateral positions, -1 off the road."""
        y = np.asarray(y_m, dtype=np.float64)
        k = np.searchsorted(self.markings_y_m, y, side="right") - 1
        return np.where((k < 0) | (k >= self.n_lanes) | ~np.isfinite(y), -1, k)


@dataclass(frozen=True)
class EpisodeTracks:
    """Every vehicle's state at the simulation frames recorded so far (highway-env coordinates, box centres).

    t_s: (T,) simulation time of each frame [s], ascending (frame 0: the state after ``reset``).
    xy_m, vxy_mps: (V, T, 2). heading_rad: (V, T). crashed: (V, T) bool (highway-env's flag).
    ids: (V,) int > 0, stable over the episode; length_m, width_m: (V,). ego: the ego's row.
    ego_on_road: (T,) bool, the ego inside its lane's bounds (highway-env's ``on_road``).
    """

    t_s: np.ndarray
    xy_m: np.ndarray
    vxy_mps: np.ndarray
    heading_rad: np.ndarray
    crashed: np.ndarray
    ids: np.ndarray
    length_m: np.ndarray
    width_m: np.ndarray
    ego: int
    ego_on_road: np.ndarray

    def __post_init__(self) -> None:
        v, t = len(self.ids), len(self.t_s)
        if t < 1:
            raise ValueError("EpisodeTracks needs at least one frame")
        for name, shape in (("xy_m", (v, t, 2)), ("vxy_mps", (v, t, 2)), ("heading_rad", (v, t)),
                            ("crashed", (v, t)), ("length_m", (v,)), ("width_m", (v,)), ("ego_on_road", (t,))):
            if np.shape(getattr(self, name)) != shape:
                raise ValueError(f"EpisodeTracks.{name} has shape {np.shape(getattr(self, name))}, expected {shape}")
        if not 0 <= self.ego < v:
            raise ValueError(f"EpisodeTracks.ego {self.ego} outside the {v} vehicles")
        if (np.diff(self.t_s) <= 0).any():
            raise ValueError("EpisodeTracks.t_s must ascend")

    @property
    def n_frames(self) -> int:
        return len(self.t_s)

    def upto(self, n_frames: int) -> EpisodeTracks:
        """The first ``n_frames`` frames (views, no copy)."""
        return EpisodeTracks(self.t_s[:n_frames], self.xy_m[:, :n_frames], self.vxy_mps[:, :n_frames],
                             self.heading_rad[:, :n_frames], self.crashed[:, :n_frames], self.ids, self.length_m,
                             self.width_m, self.ego, self.ego_on_road[:n_frames])


def resample(t_s: np.ndarray, xy_m: np.ndarray, vxy_mps: np.ndarray, at_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities (V, K, 2) at the times ``at_s`` (K,) from states (V, T, 2) at ``t_s`` (T,).

    Linear between frames; before the first frame at constant velocity from it (the back-fill); after the last,
    the last state.
    """
    t = np.asarray(t_s, dtype=np.float64)
    at = np.asarray(at_s, dtype=np.float64)
    i = np.clip(np.searchsorted(t, at, side="right") - 1, 0, len(t) - 1)
    j = np.minimum(i + 1, len(t) - 1)
    span = t[j] - t[i]
    w = np.where(span > 0, np.clip((at - t[i]) / np.where(span > 0, span, 1.0), 0.0, 1.0), 0.0)[None, :, None]
    xy = np.asarray(xy_m, dtype=np.float64)
    vxy = np.asarray(vxy_mps, dtype=np.float64)
    pos = xy[:, i] * (1.0 - w) + xy[:, j] * w
    vel = vxy[:, i] * (1.0 - w) + vxy[:, j] * w
    before = (at < t[0])[None, :, None]
    back = xy[:, :1] + vxy[:, :1] * (at - t[0])[None, :, None]
    return np.where(before, back, pos), np.where(before, vxy[:, :1], vel)


def history_times(now_s: float) -> np.ndarray:
    """(``N_HISTORY``,) the 25 Hz instants of a scenario's history ending at ``now_s`` (frame ``T0_INDEX``)."""
    return now_s - (T0_INDEX - np.arange(N_HISTORY)) * DT_S


def neighbour_rows(tracks: EpisodeTracks) -> np.ndarray:
    """Rows of the vehicles a planner sees at the last frame: the others within ``NEIGHBOUR_RADIUS_M`` of the
    ego's centre, the ``MAX_NEIGHBOURS`` nearest first (distances at 1 mm, ties: lower id)."""
    now = tracks.xy_m[:, -1]
    dist = np.hypot(*(now - now[tracks.ego]).T)
    rows = np.flatnonzero((dist <= NEIGHBOUR_RADIUS_M) & (np.arange(len(tracks.ids)) != tracks.ego))
    order = np.lexsort((tracks.ids[rows], np.round(dist[rows], 3)))
    return rows[order][:MAX_NEIGHBOURS]


@dataclass(frozen=True)
class ScenarioLabel:
    """What names an episode's scenarios: ``name`` (the scenario id's prefix), ``recording_id`` (an int, the
    episode's seed) and ``recording_key`` (a content key of the environment, its configuration and the seed)."""

    name: str
    recording_id: int
    recording_key: str


def scenario_view(tracks: EpisodeTracks, road: RoadLayout, label: ScenarioLabel) -> ScenarioBatch:
    """What a planner sees at the last recorded frame: a history-only ``ScenarioBatch`` of one (module doc)."""
    now_s = float(tracks.t_s[-1])
    xy, vxy = resample(tracks.t_s, tracks.xy_m, tracks.vxy_mps, history_times(now_s))  # (V, 75, 2)
    centre = tracks.xy_m[tracks.ego, -1].astype(np.float64)
    flip = np.array([1.0, -1.0])
    ego_xy = (xy - centre) * flip  # ego frame: x forward, y left
    ego_v = vxy * flip
    e = tracks.ego
    acc = np.diff(ego_v[e], axis=0, prepend=ego_v[e, :1]) / DT_S
    acc[0] = acc[1] if len(acc) > 1 else acc[0]
    rows = neighbour_rows(tracks)
    n = MAX_NEIGHBOURS
    nbr_id = np.zeros(n, np.int32)
    nbr_class = np.full(n, VEHICLE_CLASS_NONE, np.int8)
    nbr_len, nbr_wid = np.zeros(n, np.float32), np.zeros(n, np.float32)
    nbr_xy = np.full((n, N_HISTORY, 2), np.nan, np.float32)
    nbr_v = np.full((n, N_HISTORY, 2), np.nan, np.float32)
    nbr_valid = np.zeros((n, N_HISTORY), bool)
    nbr_lane = np.zeros((n, N_HISTORY), np.int8)
    k = len(rows)
    nbr_id[:k] = tracks.ids[rows]
    nbr_class[:k] = VEHICLE_CLASS_CAR
    nbr_len[:k], nbr_wid[:k] = tracks.length_m[rows], tracks.width_m[rows]
    nbr_xy[:k], nbr_v[:k] = ego_xy[rows], ego_v[rows]
    nbr_valid[:k] = True
    nbr_lane[:k] = road.highd_lane_id(xy[rows, :, 1])
    markings = (centre[1] - road.markings_y_m)[::-1]  # ascending ego-frame y: the right edge first
    frame0 = round(now_s * FRAME_RATE_HZ)
    return ScenarioBatch.from_single(
        scenario_id=f"{label.name}_f{frame0}", recording_id=label.recording_id, recording_key=label.recording_key,
        location_id=0, ego_id=int(tracks.ids[e]), frame0=frame0, driving_direction=DRIVING_DIRECTION_LOWER,
        speed_limit_mps=np.float32(road.speed_limit_mps), ego_class=np.int8(VEHICLE_CLASS_CAR),
        ego_length_m=np.float32(tracks.length_m[e]), ego_width_m=np.float32(tracks.width_m[e]),
        ego_xy_m=ego_xy[e].astype(np.float32), ego_vxy_mps=ego_v[e].astype(np.float32),
        ego_axy_mps2=acc.astype(np.float32), ego_lane_id=road.highd_lane_id(xy[e, :, 1]),
        nbr_id=nbr_id, nbr_class=nbr_class, nbr_length_m=nbr_len, nbr_width_m=nbr_wid, nbr_xy_m=nbr_xy,
        nbr_vxy_mps=nbr_v, nbr_valid=nbr_valid, nbr_lane_id=nbr_lane,
        marking_y_m=markings.astype(np.float32),
        marking_is_edge=np.isin(np.arange(len(markings)), [0, len(markings) - 1]),
        lane_ids=road.lane_ids[::-1].copy(),
        ctx_id=np.zeros(0, np.int32), ctx_class=np.zeros(0, np.int8), ctx_length_m=np.zeros(0, np.float32),
        ctx_width_m=np.zeros(0, np.float32), ctx_xy_m=np.zeros((0, N_FUTURE, 2), np.float32),
        ctx_vxy_mps=np.zeros((0, N_FUTURE, 2), np.float32), ctx_valid=np.zeros((0, N_FUTURE), bool),
    )


def plan_to_world(plan_xy_m: np.ndarray, plan_vxy_mps: np.ndarray, centre_xy_m: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """A plan (F, 2) in the ego frame of a view made about ``centre_xy_m`` (highway-env coordinates) back in
    highway-env coordinates: positions and velocities (F, 2)."""
    flip = np.array([1.0, -1.0])
    return (np.asarray(plan_xy_m, np.float64) * flip + np.asarray(centre_xy_m, np.float64),
            np.asarray(plan_vxy_mps, np.float64) * flip)


def episode_recording(tracks: EpisodeTracks, road: RoadLayout, recording_id: int) -> Recording:
    """The episode as a HighD recording at 25 Hz (module doc), every vehicle of every frame."""
    t = np.asarray(tracks.t_s, dtype=np.float64)
    at = t[0] + np.arange(int(np.floor((t[-1] - t[0]) / DT_S + 1e-9)) + 1) * DT_S
    xy, vxy = resample(t, tracks.xy_m, tracks.vxy_mps, at)  # (V, K, 2)
    acc = np.gradient(vxy, DT_S, axis=1) if len(at) > 1 else np.zeros_like(vxy)
    v, k = xy.shape[:2]
    length = np.repeat(tracks.length_m.astype(np.float64), k)
    width = np.repeat(tracks.width_m.astype(np.float64), k)
    states = pd.DataFrame({
        "frame": np.tile(np.arange(1, k + 1), v), "id": np.repeat(tracks.ids.astype(np.int64), k),
        "x": xy[..., 0].ravel() - length / 2.0, "y": xy[..., 1].ravel() + road.image_shift_m - width / 2.0,
        "width": length, "height": width,
        "xVelocity": vxy[..., 0].ravel(), "yVelocity": vxy[..., 1].ravel(),
        "xAcceleration": acc[..., 0].ravel(), "yAcceleration": acc[..., 1].ravel(),
    })
    vehicles = pd.DataFrame({"id": tracks.ids.astype(np.int64),
                             "class": np.where(tracks.length_m > TRUCK_LENGTH_M, "Truck", "Car"),
                             "drivingDirection": DRIVING_DIRECTION_LOWER})
    limit = road.speed_limit_mps
    return build_recording(states, vehicles, recording_id=recording_id,
                           upper_markings_y_m=road.upper_markings_image_m.tolist(),
                           lower_markings_y_m=road.lower_markings_image_m.tolist(), frame_rate_hz=int(FRAME_RATE_HZ),
                           speed_limit_mps=float(limit) if np.isfinite(limit) else -1.0)
