"""Neighbour prediction modes: constant velocity, IDM (paper), ground-truth oracle."""

from __future__ import annotations

import numpy as np
import pytest

from letspi.constants import DT_S, MAX_NEIGHBOURS, N_FUTURE, T0_INDEX
from letspi.physics.neighbours import (
    NeighbourPredictionMode,
    ground_truth_oracle,
    idm_leaders,
    predict_constant_velocity,
    predict_idm,
    predict_neighbours,
)
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import concat_batches

T = np.arange(1, N_FUTURE + 1) * DT_S


def _batch(neighbours: list[VehicleSpec], ego_speed_mps: float = 30.0):
    return straight_road_scenario(ego_speed_mps=ego_speed_mps, neighbours=neighbours)


@pytest.mark.parametrize("mode", list(NeighbourPredictionMode))
def test_shapes_and_dispatch(mode: NeighbourPredictionMode) -> None:
    batch = concat_batches([_batch([VehicleSpec(20.0, 25.0)]), _batch([])])
    pred = predict_neighbours(batch, mode.value)
    assert pred.xy_m.shape == (2, MAX_NEIGHBOURS, N_FUTURE, 2)
    assert pred.vxy_mps.shape == (2, MAX_NEIGHBOURS, N_FUTURE, 2)
    assert pred.valid.shape == (2, MAX_NEIGHBOURS, N_FUTURE)
    assert pred.valid[0, 0].all() and not pred.valid[0, 1:].any() and not pred.valid[1].any()
    assert np.isfinite(pred.xy_m).all() and np.isfinite(pred.vxy_mps).all()


def test_constant_velocity_is_linear() -> None:
    batch = _batch([VehicleSpec(20.0, 25.0, lane_offset=1, accel_mps2=-2.0)])
    pred = predict_constant_velocity(batch)
    np.testing.assert_allclose(pred.xy_m[0, 0, :, 0], 20.0 + 25.0 * T, atol=1e-4)
    np.testing.assert_allclose(pred.xy_m[0, 0, :, 1], 3.75, atol=1e-6)
    np.testing.assert_allclose(pred.vxy_mps[0, 0, :, 0], 25.0, atol=1e-5)


def test_not_visible_at_t0_is_invalid_for_predictions_but_not_for_the_oracle() -> None:
    late = VehicleSpec(20.0, 25.0, visible_from_index=T0_INDEX + 10)
    batch = _batch([late])
    for pred in (predict_constant_velocity(batch), predict_idm(batch)):
        assert not pred.valid[0, 0].any()
        assert (pred.xy_m[0, 0] == 0).all()
    oracle = ground_truth_oracle(batch)
    assert not oracle.valid[0, 0, :9].any() and oracle.valid[0, 0, 9:].all()


def test_oracle_is_the_recorded_future() -> None:
    batch = _batch([VehicleSpec(20.0, 25.0, accel_mps2=-1.5)])
    oracle = ground_truth_oracle(batch)
    np.testing.assert_allclose(oracle.xy_m[0, 0], batch.nbr_xy_m[0, 0, T0_INDEX + 1 :], atol=0)


def test_idm_leaders() -> None:
    nbrs = [
        VehicleSpec(30.0, 30.0),  # 0: ahead of the ego, behind 1 -> leader 1
        VehicleSpec(60.0, 20.0),  # 1: front of the lane -> no leader
        VehicleSpec(-25.0, 30.0),  # 2: behind the ego -> leader: the ego (slot N)
        VehicleSpec(10.0, 30.0, lane_offset=1),  # 3: alone in the left lane -> none
        VehicleSpec(45.0, 30.0, visible_from_index=T0_INDEX + 1),  # 4: not visible -> none, never a leader
    ]
    leaders = idm_leaders(_batch(nbrs))
    assert leaders[0, :5].tolist() == [1, -1, MAX_NEIGHBOURS, -1, -1]


def test_idm_follower_brakes_for_slow_leader_and_keeps_lane() -> None:
    nbrs = [VehicleSpec(30.0, 30.0), VehicleSpec(60.0, 20.0)]
    pred = predict_idm(_batch(nbrs))
    follower_v = pred.vxy_mps[0, 0, :, 0]
    leader_v = pred.vxy_mps[0, 1, :, 0]
    assert follower_v[0] < 30.0 and 17.0 < follower_v[-1] < 22.0  # brakes towards the leader's 20 m/s
    np.testing.assert_allclose(leader_v, 20.0, atol=1e-9)  # free, at its desired (history) speed
    gap = pred.xy_m[0, 1, :, 0] - pred.xy_m[0, 0, :, 0] - 4.5
    assert gap.min() > 2.0
    assert np.all(pred.xy_m[0, :2, :, 1] == 0.0)


def test_idm_follower_of_the_ego_uses_ego_constant_velocity() -> None:
    # a faster car 12 m behind the ego closes in and must brake for the (constant-velocity) ego
    pred = predict_idm(_batch([VehicleSpec(-12.0, 35.0)], ego_speed_mps=25.0))
    gap = 25.0 * T - pred.xy_m[0, 0, :, 0] - 4.5
    assert gap.min() > 0.0
    assert pred.vxy_mps[0, 0, -1, 0] < 30.0
