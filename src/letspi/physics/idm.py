"""Intelligent Driver Model (Treiber, Hennecke & Helbing 2000), batched.

``a = a_max [1 - (v / v0)^delta - (s* / s)^2]``, ``s* = s0 + max(0, v T + v dv / (2 sqrt(a_max b)))``, gap s
bumper to bumper, dv = v - v_leader; Treiber's values (``CAR_IDM``, ``TRUCK_IDM``). Safeguards: s floored at s0 / 2,
a clipped to [-9, a_max] m/s², v >= 0, v0 >= 1 m/s; semi-implicit Euler. ``rollout_idm_ego``'s in-lane leader:
centre offset < half a lane, or boxes overlapping laterally.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from letspi.constants import DT_S, T0_INDEX
from letspi.physics.lanes import lane_width_m
from letspi.physics.params import FloatOrArray
from letspi.physics.types import NeighbourPrediction, RolloutResult
from letspi.scenario.types import VEHICLE_CLASS_TRUCK, ScenarioBatch

IDM_MIN_ACCEL_MPS2 = -9.0
MIN_DESIRED_SPEED_MPS = 1.0
GAP_FLOOR_FRACTION = 0.5


@dataclass(frozen=True)
class IdmParams:
    """IDM parameters: time headway T [s], jam gap s0 [m], max acceleration a [m/s²], comfortable deceleration b
    [m/s²], exponent delta; each a float or an array broadcastable to the vehicles (``for_classes``)."""

    time_headway_s: FloatOrArray = 1.5
    min_gap_m: FloatOrArray = 2.0
    max_accel_mps2: FloatOrArray = 1.0
    comfort_decel_mps2: FloatOrArray = 2.0
    delta: FloatOrArray = 4.0

    @classmethod
    def for_classes(cls, vehicle_class: np.ndarray, car: IdmParams | None = None,
                    truck: IdmParams | None = None) -> IdmParams:
        """Per-vehicle car or truck parameters by HighD class code (anything but a truck counts as a car)."""
        car, truck = car or CAR_IDM, truck or TRUCK_IDM
        is_truck = np.asarray(vehicle_class) == VEHICLE_CLASS_TRUCK
        return cls(**{f.name: np.where(is_truck, np.asarray(getattr(truck, f.name), dtype=np.float64),
                                       np.asarray(getattr(car, f.name), dtype=np.float64))
                      for f in fields(cls)})


CAR_IDM = IdmParams()
TRUCK_IDM = IdmParams(time_headway_s=2.0, max_accel_mps2=0.7)


class IdmKernel:
    """The IDM acceleration with per-vehicle constants prepared once, for rollouts (same arithmetic as
    ``idm_acceleration``); ``desired_speed_mps`` and ``params`` broadcast to the vehicle shape."""

    def __init__(self, desired_speed_mps: np.ndarray, params: IdmParams = CAR_IDM) -> None:
        self.v0 = np.maximum(np.asarray(desired_speed_mps, dtype=np.float64), MIN_DESIRED_SPEED_MPS)
        self.a_max = np.asarray(params.max_accel_mps2, dtype=np.float64)
        b = np.asarray(params.comfort_decel_mps2, dtype=np.float64)
        self.s0 = np.asarray(params.min_gap_m, dtype=np.float64)
        self.time_headway_s = params.time_headway_s
        self.delta = params.delta
        self.two_sqrt_ab = 2.0 * np.sqrt(self.a_max * b)
        self.gap_floor_m = GAP_FLOOR_FRACTION * self.s0

    def __call__(self, speed_mps: np.ndarray, gap_m: np.ndarray, leader_speed_mps: np.ndarray) -> np.ndarray:
        """Acceleration [m/s^2]; gap_m ``inf`` without a leader (``leader_speed_mps`` then ignored)."""
        v = np.maximum(np.asarray(speed_mps, dtype=np.float64), 0.0)
        gap = np.asarray(gap_m, dtype=np.float64)
        has_leader = np.isfinite(gap)
        v_lead = np.where(has_leader, np.asarray(leader_speed_mps, dtype=np.float64), v)
        s_star = self.s0 + np.maximum(0.0, v * self.time_headway_s + v * (v - v_lead) / self.two_sqrt_ab)
        s = np.maximum(np.where(has_leader, gap, 1.0), self.gap_floor_m)
        interaction = np.where(has_leader, (s_star / s) ** 2, 0.0)
        acc = self.a_max * (1.0 - (v / self.v0) ** self.delta - interaction)
        return np.clip(acc, IDM_MIN_ACCEL_MPS2, self.a_max)


def idm_acceleration(
    speed_mps: np.ndarray,
    desired_speed_mps: np.ndarray,
    gap_m: np.ndarray,
    leader_speed_mps: np.ndarray,
    params: IdmParams = CAR_IDM,
) -> np.ndarray:
    """IDM acceleration [m/s²] with the module's safeguards; inputs broadcast together. ``gap_m``: bumper-to-bumper
    gap, ``inf`` without a leader (``leader_speed_mps`` is then ignored and may be NaN)."""
    return IdmKernel(desired_speed_mps, params)(speed_mps, gap_m, leader_speed_mps)


def desired_speed_from_history(speed_mps: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """Highest finite speed over the history frames (last axis) of ``speed_mps`` (..., H), where ``valid``; (...,),
    floored at 1 m/s."""
    v = np.asarray(speed_mps, dtype=np.float64)
    ok = np.isfinite(v) if valid is None else (np.asarray(valid, dtype=bool) & np.isfinite(v))
    best = np.where(ok, v, -np.inf).max(axis=-1)
    return np.maximum(np.where(np.isfinite(best), best, MIN_DESIRED_SPEED_MPS), MIN_DESIRED_SPEED_MPS)


def step_speed(speed_mps: np.ndarray, accel_mps2: np.ndarray, dt_s: float) -> np.ndarray:
    """Semi-implicit Euler speed update with the no-reverse floor."""
    return np.maximum(speed_mps + accel_mps2 * dt_s, 0.0)


def _neighbours_from_t0(batch: ScenarioBatch, neighbours: NeighbourPrediction
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Neighbour positions (B, N, F+1, 2), x velocities and validity (B, N, F+1): index k is t = k dt, observed at 0."""
    nxy = np.concatenate(
        [batch.nbr_xy_m[:, :, T0_INDEX : T0_INDEX + 1].astype(np.float64), neighbours.xy_m], axis=2
    )
    nvx = np.concatenate(
        [batch.nbr_vxy_mps[:, :, T0_INDEX : T0_INDEX + 1, 0].astype(np.float64), neighbours.vxy_mps[..., 0]],
        axis=2,
    )
    nvalid = np.concatenate([batch.nbr_valid[:, :, T0_INDEX : T0_INDEX + 1], neighbours.valid], axis=2)
    return nxy, nvx, nvalid & np.isfinite(nxy).all(axis=-1) & np.isfinite(nvx)


def rollout_idm_ego(
    batch: ScenarioBatch,
    neighbours: NeighbourPrediction,
    *,
    desired_speed_mps: np.ndarray | None = None,
    params: IdmParams | None = None,
    dt_s: float = DT_S,
) -> RolloutResult:
    """Planner-level IDM: the ego follows its in-lane leader among the predicted ``neighbours`` (B, N, F, ...) and
    keeps its lateral position (zero lateral velocity and acceleration). Defaults: ``desired_speed_mps`` from the
    ego's history, ``params`` by ``batch.ego_class``."""
    n = len(batch)
    f = int(neighbours.xy_m.shape[2])
    hist = batch.history_slice
    v0 = (
        desired_speed_from_history(batch.ego_vxy_mps[:, hist, 0])
        if desired_speed_mps is None
        else np.broadcast_to(np.asarray(desired_speed_mps, dtype=np.float64), (n,))
    )
    prm = IdmParams.for_classes(batch.ego_class) if params is None else params
    nxy, nvx, nvalid = _neighbours_from_t0(batch, neighbours)
    half_len = 0.5 * (batch.ego_length_m.astype(np.float64)[:, None] + np.nan_to_num(batch.nbr_length_m))
    half_wid = 0.5 * (batch.ego_width_m.astype(np.float64)[:, None] + np.nan_to_num(batch.nbr_width_m))
    in_lane_dy = np.maximum(0.5 * lane_width_m(batch.marking_y_m)[:, None], half_wid)

    x = np.nan_to_num(batch.ego_xy0_m[:, 0].astype(np.float64))
    y = np.nan_to_num(batch.ego_xy0_m[:, 1].astype(np.float64))
    v = np.maximum(np.nan_to_num(batch.ego_vxy0_mps[:, 0].astype(np.float64)), 0.0)
    xs = np.empty((n, f))
    vs = np.empty((n, f))
    accs = np.empty((n, f))
    kernel = IdmKernel(v0, prm)
    for k in range(f):
        dx = np.where(nvalid[:, :, k], nxy[:, :, k, 0], np.inf) - x[:, None]
        dy = np.abs(np.where(nvalid[:, :, k], nxy[:, :, k, 1], np.inf) - y[:, None])
        gap = np.where((dx > 0.0) & (dy < in_lane_dy), dx - half_len, np.inf)
        lead = np.argmin(gap, axis=1)
        lead_gap = np.take_along_axis(gap, lead[:, None], axis=1)[:, 0]
        lead_v = np.take_along_axis(nvx[:, :, k], lead[:, None], axis=1)[:, 0]
        acc = kernel(v, lead_gap, lead_v)
        new_v = step_speed(v, acc, dt_s)
        accs[:, k] = (new_v - v) / dt_s
        v = new_v
        x = x + v * dt_s
        xs[:, k] = x
        vs[:, k] = v
    zeros = np.zeros((n, f))
    return RolloutResult(
        xy_m=np.stack([xs, np.broadcast_to(y[:, None], (n, f))], axis=-1),
        vxy_mps=np.stack([vs, zeros], axis=-1),
        axy_mps2=np.stack([accs, zeros], axis=-1),
        dt_s=dt_s,
    )
