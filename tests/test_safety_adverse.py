"""Adverse futures (``letspi.safety.adverse``): hand-computed trajectories on synthetic scenes."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from letspi.constants import DT_S, N_FUTURE, T0_INDEX
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.safety.adverse import (
    ADVERSE_FUTURES,
    AdverseFuture,
    AdverseSettings,
    adverse_futures,
    check_futures,
)
from letspi.scenario.build import LANE_WIDTH_M, VehicleSpec, straight_road_scenario
from letspi.scenario.types import ScenarioBatch

T = np.arange(1, N_FUTURE + 1) * DT_S


def _futures(batch: ScenarioBatch, settings: AdverseSettings | None = None):  # type: ignore[no-untyped-def]
    hist = batch.history()
    base = predict_neighbours(hist, NeighbourPredictionMode.IDM)
    return hist, base, adverse_futures(hist, base, settings)


def _index(name: AdverseFuture) -> int:
    return ADVERSE_FUTURES.index(name)


def _with_lateral_speed(batch: ScenarioBatch, slot: int, vy_mps: float) -> ScenarioBatch:
    """The neighbour in ``slot`` drifts sideways at ``vy_mps`` over the whole window (y(t0) unchanged)."""
    t = (np.arange(batch.nbr_xy_m.shape[2]) - T0_INDEX) * DT_S
    xy = batch.nbr_xy_m.copy()
    vxy = batch.nbr_vxy_mps.copy()
    xy[0, slot, :, 1] += (vy_mps * t).astype(xy.dtype)
    vxy[0, slot, :, 1] = vy_mps
    return replace(batch, nbr_xy_m=xy, nbr_vxy_mps=vxy)


def test_the_leader_in_each_nearby_lane_brakes_as_computed_by_hand() -> None:
    batch = straight_road_scenario(ego_speed_mps=30.0, neighbours=[
        VehicleSpec(30.0, 30.0), VehicleSpec(60.0, 30.0), VehicleSpec(20.0, 28.0, lane_offset=1),
        VehicleSpec(-25.0, 30.0)])
    _, base, fut = _futures(batch)
    a = _index(AdverseFuture.LEADER_BRAKES)
    assert fut.applies[a, 0]
    xy, vxy = fut.xy_m[a, 0], fut.vxy_mps[a, 0]
    k = round(1.0 / DT_S) - 1  # t = 1 s
    assert vxy[0, k, 0] == pytest.approx(30.0 - 6.0)
    assert xy[0, k, 0] == pytest.approx(30.0 + 30.0 - 3.0)  # x0 + v0 t - a t^2 / 2
    end = N_FUTURE - 1  # 2 s of braking (-12 m/s), then the lower speed
    assert vxy[0, end, 0] == pytest.approx(18.0)
    assert xy[0, end, 0] == pytest.approx(30.0 + 30.0 * 2 - 12.0 + 18.0 * (T[end] - 2.0))
    assert vxy[2, end, 0] == pytest.approx(28.0 - 12.0)  # the left lane's leader brakes too
    # the vehicle ahead of the leader and the follower keep the base prediction
    np.testing.assert_array_equal(xy[1], base.xy_m[0, 1])
    np.testing.assert_array_equal(xy[3], base.xy_m[0, 3])


def test_braking_stops_at_standstill_and_nobody_ahead_means_the_future_does_not_apply() -> None:
    batch = straight_road_scenario(ego_speed_mps=10.0, neighbours=[VehicleSpec(30.0, 5.0)])
    _, _, fut = _futures(batch, AdverseSettings(brake_decel_mps2=8.0, brake_duration_s=3.0))
    a = _index(AdverseFuture.LEADER_BRAKES)
    assert fut.vxy_mps[a, 0, 0, -1, 0] == 0.0
    assert fut.xy_m[a, 0, 0, -1, 0] == pytest.approx(30.0 + 5.0**2 / (2 * 8.0), abs=0.01)
    alone = straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(-30.0, 30.0, lane_offset=1)])
    _, base, fut = _futures(alone)
    assert not fut.applies[a, 0]
    np.testing.assert_array_equal(fut.xy_m[a, 0], base.xy_m[0])


def test_a_car_drifting_towards_the_ego_lane_completes_its_lane_change() -> None:
    batch = straight_road_scenario(ego_speed_mps=30.0, neighbours=[
        VehicleSpec(10.0, 30.0, lane_offset=1), VehicleSpec(15.0, 30.0, lane_offset=-1)])
    batch = _with_lateral_speed(batch, 0, -0.5)  # left lane, moving right: towards the ego
    batch = _with_lateral_speed(batch, 1, -0.5)  # right lane, moving right: away
    _, base, fut = _futures(batch)
    a = _index(AdverseFuture.CUT_IN)
    assert fut.applies[a, 0]
    y, vy = fut.xy_m[a, 0, 0, :, 1], fut.vxy_mps[a, 0, 0, :, 1]
    y0 = float(batch.nbr_xy_m[0, 0, T0_INDEX, 1])
    assert y0 == pytest.approx(LANE_WIDTH_M)
    # at the larger of its own 0.5 m/s and the 0.94 m/s of a 4 s lane change, to the ego lane's centre
    k = round(2.0 / DT_S) - 1
    assert y[k] == pytest.approx(y0 - 0.94 * 2.0)
    assert vy[k] == pytest.approx(-0.94)
    assert y[-1] == pytest.approx(0.0)
    assert vy[-1] == 0.0
    np.testing.assert_array_equal(fut.xy_m[a, 0, 1], base.xy_m[0, 1])  # drifting away: not an actor
    np.testing.assert_array_equal(fut.xy_m[a, 0, 0, :, 0], base.xy_m[0, 0, :, 0])  # longitudinally as predicted


def test_followers_keep_their_speed() -> None:
    batch = straight_road_scenario(ego_speed_mps=20.0, neighbours=[VehicleSpec(-20.0, 35.0), VehicleSpec(40.0, 20.0)])
    _, base, fut = _futures(batch)
    a = _index(AdverseFuture.FOLLOWER_KEEPS)
    assert fut.applies[a, 0]
    np.testing.assert_allclose(fut.xy_m[a, 0, 0, :, 0], -20.0 + 35.0 * T)
    assert base.xy_m[0, 0, -1, 0] < -20.0 + 35.0 * T[-1] - 1.0  # IDM would have braked behind the ego
    np.testing.assert_array_equal(fut.xy_m[a, 0, 1], base.xy_m[0, 1])


def test_a_plan_that_cannot_stop_for_a_braking_leader_fails_that_future_only() -> None:
    batch = straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(25.0, 30.0)])
    hist, base, fut = _futures(batch)
    keep_speed = np.stack([30.0 * T, np.zeros_like(T)], axis=-1)[None]
    velocity = np.broadcast_to(np.array([30.0, 0.0]), keep_speed.shape).copy()
    checks = check_futures(hist, keep_speed, velocity, base, fut)
    assert checks.names == ("predicted", "leader-brakes", "cut-in", "follower-keeps")
    assert not checks.collision[0, 0] and checks.collision[0, 1]
    # contact when the 20.5 m bumper gap is used up: 12 m in the 2 s of braking, then 12 m/s closing
    assert checks.contact_time_s[0, 1] == pytest.approx(2.0 + (20.5 - 12.0) / 12.0, abs=DT_S)
    settings = AdverseSettings()
    assert checks.failed_names(settings) == ["leader-brakes"]
    assert checks.failed(settings)[0].tolist() == [True, False, False]
    # a plan that brakes as hard as the leader keeps its distance
    v = np.maximum(30.0 - 6.0 * np.minimum(T, 2.0), 0.0)
    x = np.cumsum(v) * DT_S
    braking = check_futures(hist, np.stack([x, 0 * x], -1)[None], np.stack([v, 0 * v], -1)[None], base, fut)
    assert braking.failed_names(settings) == [""]


def test_futures_are_batched_per_scenario() -> None:
    one = straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(25.0, 30.0)])
    two = straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(-30.0, 30.0, lane_offset=-1)])
    both = ScenarioBatch(**{f: np.concatenate([getattr(one, f), getattr(two, f)]) for f in one.__dataclass_fields__})
    _, _, fut = _futures(both)
    _, _, f1 = _futures(one)
    _, _, f2 = _futures(two)
    np.testing.assert_array_equal(fut.xy_m[:, :1], f1.xy_m)
    np.testing.assert_array_equal(fut.xy_m[:, 1:], f2.xy_m)
    assert fut.applies[:, 0].tolist() == [True, False, False]  # a leader, nobody behind
    assert fut.applies[:, 1].tolist() == [False, False, True]  # a follower in the right lane
