"""IDM: the acceleration law, its safeguards and the planner-level ego rollout."""

from __future__ import annotations

import numpy as np
import pytest

from letspi.constants import DT_S
from letspi.physics.idm import (
    CAR_IDM,
    IDM_MIN_ACCEL_MPS2,
    TRUCK_IDM,
    IdmParams,
    desired_speed_from_history,
    idm_acceleration,
    rollout_idm_ego,
)
from letspi.physics.neighbours import predict_constant_velocity
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import VEHICLE_CLASS_CAR, VEHICLE_CLASS_TRUCK


def test_free_road_acceleration() -> None:
    assert idm_acceleration(30.0, 30.0, np.inf, np.nan) == pytest.approx(0.0)
    assert idm_acceleration(0.0, 30.0, np.inf, np.nan) == pytest.approx(CAR_IDM.max_accel_mps2)
    assert idm_acceleration(35.0, 30.0, np.inf, np.nan) < 0


def test_equilibrium_gap_gives_zero_acceleration() -> None:
    v, v0 = 20.0, 30.0
    # s_e = s* / sqrt(1 - (v / v0)^4) with dv = 0
    s_star = CAR_IDM.min_gap_m + v * CAR_IDM.time_headway_s
    s_e = s_star / np.sqrt(1.0 - (v / v0) ** 4)
    assert idm_acceleration(v, v0, s_e, v) == pytest.approx(0.0, abs=1e-12)


def test_safeguards_keep_numbers_finite() -> None:
    acc = idm_acceleration(
        np.array([30.0, 30.0, 0.0, -5.0]),
        np.array([30.0, 0.0, 30.0, 30.0]),
        np.array([0.0, -3.0, 1e-9, 50.0]),
        np.array([0.0, 0.0, 0.0, 0.0]),
    )
    assert np.isfinite(acc).all()
    assert acc.min() >= IDM_MIN_ACCEL_MPS2
    assert acc[0] == IDM_MIN_ACCEL_MPS2


def test_truck_parameters_by_class() -> None:
    prm = IdmParams.for_classes(np.array([VEHICLE_CLASS_CAR, VEHICLE_CLASS_TRUCK, -1]))
    np.testing.assert_array_equal(prm.max_accel_mps2, [CAR_IDM.max_accel_mps2, TRUCK_IDM.max_accel_mps2, 1.0])
    np.testing.assert_array_equal(prm.time_headway_s, [1.5, 2.0, 1.5])


def test_desired_speed_from_history() -> None:
    v = np.array([[20.0, 25.0, 22.0], [np.nan, np.nan, np.nan], [0.0, 0.0, 0.0]])
    np.testing.assert_array_equal(desired_speed_from_history(v), [25.0, 1.0, 1.0])
    valid = np.array([[True, False, True], [False] * 3, [True] * 3])
    np.testing.assert_array_equal(desired_speed_from_history(v, valid), [22.0, 1.0, 1.0])


def test_stops_behind_stopped_leader_near_s0() -> None:
    leader = VehicleSpec(x0_m=80.0, speed_mps=0.0)
    batch = straight_road_scenario(ego_speed_mps=20.0, neighbours=[leader])
    n_steps = round(40.0 / DT_S)  # long enough to come to rest
    res = rollout_idm_ego(batch, predict_constant_velocity(batch, n_steps))
    gap = 80.0 - res.xy_m[0, :, 0] - 4.5
    assert gap.min() > 0.0
    s0 = CAR_IDM.min_gap_m
    assert s0 - 0.5 <= gap[-1] <= s0 + 1.5
    assert res.vxy_mps[0, -1, 0] < 0.1
    assert (res.vxy_mps[..., 0] >= 0).all()
    assert res.axy_mps2[..., 0].min() >= IDM_MIN_ACCEL_MPS2


def test_ego_keeps_lane_and_ignores_adjacent_cars() -> None:
    nbrs = [VehicleSpec(x0_m=15.0, speed_mps=10.0, lane_offset=1), VehicleSpec(x0_m=40.0, speed_mps=25.0)]
    batch = straight_road_scenario(ego_speed_mps=25.0, neighbours=nbrs)
    res = rollout_idm_ego(batch, predict_constant_velocity(batch))
    assert np.all(res.xy_m[0, :, 1] == 0.0) and np.all(res.vxy_mps[0, :, 1] == 0.0)
    # the slow car in the adjacent lane is no leader: no braking towards 10 m/s
    assert res.vxy_mps[0, :, 0].min() > 20.0
    gap = 40.0 + 25.0 * DT_S * np.arange(1, res.n_steps + 1) - res.xy_m[0, :, 0] - 4.5
    assert gap.min() > 20.0


def test_free_ego_accelerates_to_desired_speed() -> None:
    batch = straight_road_scenario(ego_speed_mps=20.0)
    res = rollout_idm_ego(batch, predict_constant_velocity(batch), desired_speed_mps=np.array([30.0]))
    v = res.vxy_mps[0, :, 0]
    assert np.all(np.diff(v) > 0) and v[-1] < 30.0
    assert v[-1] == pytest.approx(20.0 + CAR_IDM.max_accel_mps2 * 5.0, abs=1.5)
