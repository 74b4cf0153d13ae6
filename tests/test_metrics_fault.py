"""At-fault classification of collisions against hand-built encounters (straight road, 4.5 x 1.8 m cars)."""

from __future__ import annotations

import numpy as np
from test_metrics_helpers import T_FUT, constant_speed_plan, make

from letspi.constants import T0_INDEX
from letspi.metrics import aggregate_metrics, compute_metrics, human_future
from letspi.scenario.build import VehicleSpec
from letspi.scenario.types import ScenarioBatch, concat_batches


def _braking_plan(v0_mps: float, decel_mps2: float) -> tuple[np.ndarray, np.ndarray]:
    """(1, F, 2) plan braking at a constant rate from v0 (no stop within 5 s for the values used)."""
    x = v0_mps * T_FUT - 0.5 * decel_mps2 * T_FUT**2
    xy = np.stack([x, np.zeros_like(x)], -1)[None]
    v = np.stack([v0_mps - decel_mps2 * T_FUT, np.zeros_like(x)], -1)[None]
    return xy, v


def _swerving(spec: VehicleSpec, y_from_m: float, y_to_m: float, step0: int, steps: int) -> ScenarioBatch:
    """One neighbour that moves laterally from y_from to y_to (linearly) over future steps step0..step0+steps."""
    b = make([spec])
    f = np.arange(b.nbr_xy_m.shape[2]) - (T0_INDEX + 1)
    frac = np.clip((f - step0) / steps, 0.0, 1.0)
    b.nbr_xy_m[0, 0, :, 1] = y_from_m + (y_to_m - y_from_m) * frac
    b.nbr_vxy_mps[0, 0, :, 1] = np.where((frac > 0) & (frac < 1), (y_to_m - y_from_m) / (steps * 0.04), 0.0)
    return b


def test_follower_rear_ends_a_steady_ego_is_rear_not_at_fault() -> None:
    # ego (human future) at 25 m/s; a 30 m/s follower 10.1 m behind bumper to bumper (centre -14.6 m):
    # dx = -14.6 + 5 t overlaps (|dx| < 4.5) once t > 2.02 s: first at step 50 (t = 2.04 s)
    b = make([VehicleSpec(x0_m=-14.6, speed_mps=30.0)], ego_speed_mps=25.0)
    xy, v = human_future(b)
    m = compute_metrics(b, xy, v)
    assert m.collision[0] and m.collision_step[0] == 50 and m.collision_nbr[0] == 0
    assert m.collision_kind[0] == "rear" and not m.collision_at_fault[0]
    assert m.collision_fault_step[0] == -1 and m.collision_fault_nbr[0] == -1
    assert m.min_rear_ttc_s[0] == 0.0 and m.min_rear_ttc_nbr[0] == 0
    agg = aggregate_metrics(m)
    assert agg["cr_pct"] == 100.0 and agg["cr_at_fault_pct"] == 0.0 and agg["cr_rear_pct"] == 100.0


def test_rear_end_after_unjustified_hard_braking_is_at_fault() -> None:
    # the ego brakes at 5.5 m/s^2 with nothing ahead; the 30 m/s follower (centre -14.6 m) hits it
    # when -14.6 + 2.75 t^2 > -4.5: t > 1.916 s, step 47
    follower = VehicleSpec(x0_m=-14.6, speed_mps=30.0)
    xy, v = _braking_plan(30.0, 5.5)
    m = compute_metrics(make([follower]), xy, v)
    assert m.collision_kind[0] == "rear" and m.collision_step[0] == 47
    assert m.collision_at_fault[0] and (m.collision_fault_step[0], m.collision_fault_nbr[0]) == (47, 0)
    # the same braking behind a leader braking at 6 m/s^2 (20.5 m ahead, never reached) is justified
    leader = VehicleSpec(x0_m=25.0, speed_mps=30.0, accel_mps2=-6.0)
    m2 = compute_metrics(make([follower, leader]), xy, v)
    assert m2.collision_kind[0] == "rear" and m2.collision_nbr[0] == 0 and not m2.collision_at_fault[0]
    # braking at 2.5 m/s^2, below the 3 m/s^2 comfort bound, is always allowed (contact at t = 2.84 s)
    m3 = compute_metrics(make([follower]), *_braking_plan(30.0, 2.5))
    assert m3.collision_kind[0] == "rear" and not m3.collision_at_fault[0]


def test_ego_lane_change_into_a_car_is_ego_side_at_fault() -> None:
    # a car alongside in the left lane (same x, same speed); the plan moves left from step 25 to 65:
    # the boxes overlap laterally once y > 3.75 - 1.8 = 1.95 m (step 46: y = 1.97 m; step 45: 1.875 m),
    # longitudinally all the time
    b = make([VehicleSpec(x0_m=0.0, speed_mps=30.0, lane_offset=1)])
    y = 3.75 * np.clip((np.arange(125) - 25) / 40.0, 0.0, 1.0)
    xy, v = constant_speed_plan(30.0, y_m=y)
    m = compute_metrics(b, xy, v)
    assert m.collision[0] and m.collision_step[0] == 46
    assert m.collision_kind[0] == "side" and m.collision_at_fault[0]
    assert aggregate_metrics(m)["cr_side_pct"] == 100.0


def test_neighbour_swerving_into_a_straight_ego_is_side_not_at_fault() -> None:
    b = _swerving(VehicleSpec(x0_m=0.0, speed_mps=30.0, lane_offset=1), 3.75, 0.0, 25, 50)
    xy, v = human_future(b)
    m = compute_metrics(b, xy, v)
    assert m.collision[0] and m.collision_kind[0] == "side" and not m.collision_at_fault[0]


def test_ego_driving_into_a_stopped_leader_is_ego_front_at_fault() -> None:
    # stopped car 60 m ahead (centre); 30 m/s: 60 - 30 t < 4.5 once t > 1.85 s: step 46 (t = 1.88 s)
    b = make([VehicleSpec(x0_m=60.0, speed_mps=0.0)])
    xy, v = constant_speed_plan(30.0)
    m = compute_metrics(b, xy, v)
    assert (m.collision_step[0], m.collision_nbr[0]) == (46, 0)
    assert m.collision_kind[0] == "front" and m.collision_at_fault[0]
    assert aggregate_metrics(m)["cr_front_pct"] == 100.0


def test_cut_in_within_the_reaction_time_is_not_the_egos_fault() -> None:
    # a 25 m/s car moves from the left lane into the ego's path over steps 0..12 (y < 1.8 m, i.e. lateral
    # overlap, from step 7). Close ahead (centre 8 m) the 30 m/s ego hits it at t > 0.7 s (step 17),
    # 10 steps (0.4 s) after it cut in: side, its fault. Further ahead (14.6 m) the contact comes at
    # step 50, 1.7 s after the cut-in: the ego had time to brake: front, at fault.
    close = _swerving(VehicleSpec(x0_m=8.0, speed_mps=25.0, lane_offset=1), 3.75, 0.0, 0, 12)
    far = _swerving(VehicleSpec(x0_m=14.6, speed_mps=25.0, lane_offset=1), 3.75, 0.0, 0, 12)
    both = concat_batches([close, far])
    xy, v = constant_speed_plan(30.0)
    m = compute_metrics(both, np.repeat(xy, 2, 0), np.repeat(v, 2, 0))
    assert m.collision_step.tolist() == [17, 50]
    assert m.collision_kind.tolist() == ["side", "front"]
    assert m.collision_at_fault.tolist() == [False, True]


def test_first_kind_and_any_fault_with_two_contacts() -> None:
    # a follower hits the steady ego at step 50 (rear, not at fault); a stopped car 100 m ahead is hit
    # when 100 - 25 t < 4.5: t > 3.82 s, step 95 (front, at fault)
    b = make([VehicleSpec(x0_m=-14.6, speed_mps=30.0), VehicleSpec(x0_m=100.0, speed_mps=0.0)], ego_speed_mps=25.0)
    xy, v = human_future(b)
    m = compute_metrics(b, xy, v)
    assert m.collision_kind[0] == "rear" and m.collision_nbr[0] == 0  # the first contact
    assert m.collision_at_fault[0] and (m.collision_fault_step[0], m.collision_fault_nbr[0]) == (95, 1)


def test_no_contact_is_none() -> None:
    b = make([VehicleSpec(x0_m=40.0, speed_mps=30.0)])
    m = compute_metrics(b, *human_future(b))
    assert m.collision_kind[0] == "none" and not m.collision_at_fault[0] and m.collision_fault_step[0] == -1
