"""Hand-built straight-road scenarios with known answers: constant accelerations (speed floored at 0) over the
whole 8 s window, already in the ego frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from letspi.constants import DT_S, MAX_NEIGHBOURS, N_FUTURE, N_TOTAL, T0_INDEX
from letspi.scenario.types import VEHICLE_CLASS_CAR, VEHICLE_CLASS_NONE, ScenarioBatch

LANE_WIDTH_M = 3.75


@dataclass(frozen=True)
class VehicleSpec:
    """A neighbour on the straight road: ``x0_m`` its centre's x at t = 0 in the ego frame; ``lane_offset`` lanes to
    the left of the ego's (+1 left, -1 right); ``y_offset_m`` a shift within the lane."""

    x0_m: float
    speed_mps: float
    lane_offset: int = 0
    accel_mps2: float = 0.0
    y_offset_m: float = 0.0
    length_m: float = 4.5
    width_m: float = 1.8
    vehicle_class: int = VEHICLE_CLASS_CAR
    visible_from_index: int = 0


def _kinematics(x0_m: float, v0_mps: float, a_mps2: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions, speeds, accelerations over the window for constant acceleration, speed >= 0."""
    t_s = (np.arange(N_TOTAL) - T0_INDEX) * DT_S
    v = v0_mps + a_mps2 * t_s
    x = x0_m + v0_mps * t_s + 0.5 * a_mps2 * t_s**2
    a = np.full(N_TOTAL, a_mps2)
    if a_mps2 < 0 and v0_mps > 0:
        t_stop = v0_mps / -a_mps2
        stopped = t_s > t_stop
        x = np.where(stopped, x0_m + v0_mps * t_stop + 0.5 * a_mps2 * t_stop**2, x)
        v = np.where(stopped, 0.0, v)
        a = np.where(stopped, 0.0, a)
    return x, v, a


def straight_road_scenario(
    *,
    ego_speed_mps: float = 30.0,
    ego_accel_mps2: float = 0.0,
    neighbours: list[VehicleSpec] | tuple[VehicleSpec, ...] = (),
    context: list[VehicleSpec] | tuple[VehicleSpec, ...] = (),
    n_lanes: int = 3,
    ego_lane_index: int = 1,
    lane_width_m: float = LANE_WIDTH_M,
    ego_length_m: float = 4.5,
    ego_width_m: float = 1.8,
    scenario_id: str = "synthetic",
) -> ScenarioBatch:
    """A batch of one driving-direction-2 scenario on ``n_lanes`` lanes; ``ego_lane_index`` 0 = rightmost lane. The ego
    drives at its lane's centre; lane ids are HighD's for an ``n_lanes`` + ``n_lanes`` road. ``context`` vehicles are
    scored but never shown to a planner (future frames only, ids from 100)."""
    if not 0 <= ego_lane_index < n_lanes:
        raise ValueError(f"ego_lane_index {ego_lane_index} outside 0..{n_lanes - 1}")
    if len(neighbours) > MAX_NEIGHBOURS:
        raise ValueError(f"at most {MAX_NEIGHBOURS} neighbours, got {len(neighbours)}")
    marking_y = (np.arange(n_lanes + 1) - ego_lane_index - 0.5) * lane_width_m
    lane_ids = np.array([2 * n_lanes + 2 - k for k in range(n_lanes)], dtype=np.int8)
    ex, ev, ea = _kinematics(0.0, ego_speed_mps, ego_accel_mps2)
    ego_xy = np.stack([ex, np.zeros(N_TOTAL)], axis=-1)
    nbr = _neighbour_arrays(neighbours, lane_width_m, marking_y, lane_ids)
    ctx_xy, ctx_v, ctx_valid = _context_arrays(context, lane_width_m)
    c = len(context)
    edge = np.zeros(n_lanes + 1, dtype=bool)
    edge[[0, -1]] = True
    return ScenarioBatch.from_single(
        scenario_id=scenario_id,
        recording_id=0,
        recording_key="synthetic",
        location_id=0,
        ego_id=1,
        frame0=T0_INDEX + 1,
        driving_direction=2,
        speed_limit_mps=float("nan"),
        ego_class=VEHICLE_CLASS_CAR,
        ego_length_m=ego_length_m,
        ego_width_m=ego_width_m,
        ego_xy_m=ego_xy.astype(np.float32),
        ego_vxy_mps=np.stack([ev, np.zeros(N_TOTAL)], -1).astype(np.float32),
        ego_axy_mps2=np.stack([ea, np.zeros(N_TOTAL)], -1).astype(np.float32),
        ego_lane_id=_lane_id_of(np.zeros(N_TOTAL), marking_y, lane_ids).astype(np.int8),
        **nbr,
        marking_y_m=marking_y.astype(np.float32),
        marking_is_edge=edge,
        lane_ids=lane_ids,
        ctx_id=np.arange(100, 100 + c, dtype=np.int32),
        ctx_class=np.array([spec.vehicle_class for spec in context], dtype=np.int8),
        ctx_length_m=np.array([spec.length_m for spec in context], dtype=np.float32),
        ctx_width_m=np.array([spec.width_m for spec in context], dtype=np.float32),
        ctx_xy_m=ctx_xy.astype(np.float32),
        ctx_vxy_mps=ctx_v.astype(np.float32),
        ctx_valid=ctx_valid,
    )


def _lane_id_of(y_m: np.ndarray, marking_y_m: np.ndarray, lane_ids: np.ndarray) -> np.ndarray:
    """HighD lane ids of lateral positions ``y_m`` on the road with markings ``marking_y_m`` (M,)
    and lane ids ``lane_ids`` (M - 1,); off the road counts as the nearest lane."""
    k = np.clip(np.searchsorted(marking_y_m, y_m) - 1, 0, len(lane_ids) - 1)
    return lane_ids[k]


def _neighbour_arrays(
    neighbours: list[VehicleSpec] | tuple[VehicleSpec, ...],
    lane_width_m: float,
    marking_y_m: np.ndarray,
    lane_ids: np.ndarray,
) -> dict[str, np.ndarray]:
    """The ``nbr_*`` fields of one scenario (``MAX_NEIGHBOURS`` slots, the first ``len(neighbours)``
    used; ids from 2): positions and velocities (N, N_TOTAL, 2) as float32, NaN where not visible."""
    n = MAX_NEIGHBOURS
    nbr_xy = np.full((n, N_TOTAL, 2), np.nan)
    nbr_v = np.full((n, N_TOTAL, 2), np.nan)
    nbr_valid = np.zeros((n, N_TOTAL), dtype=bool)
    nbr_lane = np.zeros((n, N_TOTAL), dtype=np.int8)
    nbr_id = np.zeros(n, dtype=np.int32)
    nbr_class = np.full(n, VEHICLE_CLASS_NONE, dtype=np.int8)
    nbr_len = np.zeros(n, dtype=np.float32)
    nbr_wid = np.zeros(n, dtype=np.float32)
    for j, spec in enumerate(neighbours):
        x, v, _ = _kinematics(spec.x0_m, spec.speed_mps, spec.accel_mps2)
        y = spec.lane_offset * lane_width_m + spec.y_offset_m
        vis = np.arange(N_TOTAL) >= spec.visible_from_index
        nbr_xy[j] = np.where(vis[:, None], np.stack([x, np.full(N_TOTAL, y)], -1), np.nan)
        nbr_v[j] = np.where(vis[:, None], np.stack([v, np.zeros(N_TOTAL)], -1), np.nan)
        nbr_valid[j] = vis
        nbr_lane[j] = np.where(vis, _lane_id_of(np.full(N_TOTAL, y), marking_y_m, lane_ids), 0)
        nbr_id[j] = j + 2
        nbr_class[j] = spec.vehicle_class
        nbr_len[j] = spec.length_m
        nbr_wid[j] = spec.width_m
    return {
        "nbr_id": nbr_id,
        "nbr_class": nbr_class,
        "nbr_length_m": nbr_len,
        "nbr_width_m": nbr_wid,
        "nbr_xy_m": nbr_xy.astype(np.float32),
        "nbr_vxy_mps": nbr_v.astype(np.float32),
        "nbr_valid": nbr_valid,
        "nbr_lane_id": nbr_lane,
    }


def _context_arrays(
    context: list[VehicleSpec] | tuple[VehicleSpec, ...], lane_width_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Future positions (C, N_FUTURE, 2), velocities (C, N_FUTURE, 2) and validity (C, N_FUTURE) of
    the ``context`` vehicles (float64, NaN where not visible)."""
    c = len(context)
    ctx_xy = np.full((c, N_FUTURE, 2), np.nan)
    ctx_v = np.full((c, N_FUTURE, 2), np.nan)
    ctx_valid = np.zeros((c, N_FUTURE), dtype=bool)
    for j, spec in enumerate(context):
        x, v, _ = _kinematics(spec.x0_m, spec.speed_mps, spec.accel_mps2)
        y = spec.lane_offset * lane_width_m + spec.y_offset_m
        vis = np.arange(N_TOTAL)[T0_INDEX + 1:] >= spec.visible_from_index
        fut = slice(T0_INDEX + 1, None)
        ctx_xy[j] = np.where(vis[:, None], np.stack([x[fut], np.full(N_FUTURE, y)], -1), np.nan)
        ctx_v[j] = np.where(vis[:, None], np.stack([v[fut], np.zeros(N_FUTURE)], -1), np.nan)
        ctx_valid[j] = vis
    return ctx_xy, ctx_v, ctx_valid
