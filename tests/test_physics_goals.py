"""Goal prediction (kinematic, oracle) and the paper's goal adjustment."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from letspi.constants import DT_S, N_TOTAL, T0_INDEX
from letspi.physics.goals import (
    GoalPrediction,
    GoalPredictor,
    KinematicGoalPredictor,
    OracleGoalPredictor,
    adjust_goals,
    top_goal,
)
from letspi.scenario.build import LANE_WIDTH_M, straight_road_scenario
from letspi.scenario.types import ScenarioBatch, concat_batches

W = LANE_WIDTH_M


def _with_lateral_motion(vy_mps: float, y0_offset_m: float = 0.0, **kwargs) -> ScenarioBatch:
    """A straight-road scenario whose ego moves laterally at ``vy_mps`` through y = 0 at t = 0.

    ``y0_offset_m`` shifts the markings instead of the ego, so the ego stays at the frame origin
    but sits ``y0_offset_m`` left of its lane centre.
    """
    sc = straight_road_scenario(**kwargs)
    t = (np.arange(N_TOTAL) - T0_INDEX) * DT_S
    xy = sc.ego_xy_m.copy()
    xy[0, :, 1] = vy_mps * t
    vxy = sc.ego_vxy_mps.copy()
    vxy[0, :, 1] = vy_mps
    markings = (sc.marking_y_m - y0_offset_m).astype(np.float32)
    return dataclasses.replace(sc, ego_xy_m=xy, ego_vxy_mps=vxy, marking_y_m=markings)


def test_protocol_and_top_goal() -> None:
    assert isinstance(KinematicGoalPredictor(), GoalPredictor)
    assert isinstance(OracleGoalPredictor(), GoalPredictor)
    pred = GoalPrediction(goals_xy_m=np.array([[[1.0, 2.0], [3.0, 4.0]]]), probs=np.array([[0.7, 0.3]]))
    np.testing.assert_array_equal(top_goal(pred), [[1.0, 2.0]])
    np.testing.assert_array_equal(pred.top, [[1.0, 2.0]])
    with pytest.raises(ValueError):
        GoalPrediction(goals_xy_m=np.zeros((1, 0, 2)), probs=np.zeros((1, 0)))


@pytest.mark.parametrize("speed", [0.0, 12.0, 33.3])
def test_kinematic_constant_speed(speed: float) -> None:
    batch = straight_road_scenario(ego_speed_mps=speed)
    pred = KinematicGoalPredictor().predict_goals(batch)
    assert pred.goals_xy_m.shape == (1, 1, 2) and pred.probs.tolist() == [[1.0]]
    assert pred.top[0, 0] == pytest.approx(speed * 5.0, abs=1e-3)
    assert pred.top[0, 1] == pytest.approx(0.0, abs=1e-9)


def test_kinematic_constant_acceleration_and_clip() -> None:
    batch = concat_batches(
        [
            straight_road_scenario(ego_speed_mps=20.0, ego_accel_mps2=1.0),
            straight_road_scenario(ego_speed_mps=30.0, ego_accel_mps2=3.5),  # clipped to +2
            straight_road_scenario(ego_speed_mps=25.0, ego_accel_mps2=-3.0),  # stops after 8.3 s
            straight_road_scenario(ego_speed_mps=8.0, ego_accel_mps2=-2.0),  # stops after 4 s
        ]
    )
    goals = KinematicGoalPredictor().predict_goals(batch).top[:, 0]
    expected = [20.0 * 5 + 0.5 * 25, 30.0 * 5 + 0.5 * 2.0 * 25, 25.0 * 5 - 0.5 * 3.0 * 25, 8.0**2 / 4.0]
    np.testing.assert_allclose(goals, expected, atol=0.05)


def test_kinematic_lane_change_intention() -> None:
    batch = concat_batches(
        [
            _with_lateral_motion(0.9),  # heading left at lane-change speed
            _with_lateral_motion(-0.9),  # heading right
            _with_lateral_motion(0.15),  # drifting: stays
            _with_lateral_motion(0.5, y0_offset_m=1.2),  # already near the left line, moving on
            _with_lateral_motion(0.9, ego_lane_index=2),  # leftmost lane: nowhere further left
            _with_lateral_motion(3.0, ego_lane_index=0),  # very fast: at most one lane
        ]
    )
    goal_y = KinematicGoalPredictor().predict_goals(batch).top[:, 1]
    np.testing.assert_allclose(goal_y, [W, -W, 0.0, W - 1.2, 0.0, W], atol=1e-5)


def test_oracle_goal_is_the_recorded_endpoint() -> None:
    batch = straight_road_scenario(ego_speed_mps=27.0, ego_accel_mps2=-1.0)
    np.testing.assert_allclose(OracleGoalPredictor().predict_goals(batch).top, batch.ego_xy_m[:, -1], atol=0)


MARKINGS = np.array([[-1.5 * W, -0.5 * W, 0.5 * W, 1.5 * W]])  # 3 lanes, ego in the middle


def test_adjust_longitudinal_endpoints() -> None:
    goals = np.array([[100.0, 0.0]] * 4)
    ego = np.array([[0.0, 0.0]] * 4)
    out = adjust_goals(goals, ego, np.array([0.0, 1.0, 0.5, 7.0]), 0.0, np.repeat(MARKINGS, 4, axis=0))
    np.testing.assert_allclose(out[:, 0], [120.0, 70.0, 95.0, 70.0])
    np.testing.assert_allclose(out[:, 1], 0.0)
    # the distance is measured from the ego, not the origin
    moved = adjust_goals(np.array([[110.0, 0.0]]), np.array([[10.0, 0.0]]), 1.0, 0.0, MARKINGS)
    assert moved[0, 0] == pytest.approx(80.0)


def test_adjust_lane_factor() -> None:
    goals = np.array([[100.0, 0.0]] * 6)
    lane = np.array([-1.0, 1.0, -0.5, 0.5, -3.0, np.nan])
    out = adjust_goals(goals, np.zeros((6, 2)), np.nan, lane, np.repeat(MARKINGS, 6, axis=0))
    np.testing.assert_allclose(out[:, 1], [W, -W, 0.5 * W, -0.5 * W, W, 0.0])
    np.testing.assert_allclose(out[:, 0], 100.0)


def test_adjust_keeps_goals_on_the_road() -> None:
    # goal in the leftmost lane, shift further left -> stays at that lane's centre
    out = adjust_goals(np.array([[100.0, W], [100.0, -W - 0.4], [100.0, 9.0]]), np.zeros((3, 2)), 0.0,
                       np.array([-1.0, 1.0, 0.0]), np.repeat(MARKINGS, 3, axis=0))
    np.testing.assert_allclose(out[:, 1], [W, -W, W])


def test_adjust_random_goals_stay_between_outer_lane_centres() -> None:
    rng = np.random.default_rng(1)
    n = 500
    markings = np.repeat(MARKINGS, n, axis=0)
    goals = np.stack([rng.uniform(-50, 250, n), rng.uniform(-8, 8, n)], axis=1)
    out = adjust_goals(goals, np.zeros((n, 2)), rng.uniform(-1, 2, n), rng.uniform(-2, 2, n), markings)
    assert np.isfinite(out).all()
    assert (out[:, 1] >= -W - 1e-9).all() and (out[:, 1] <= W + 1e-9).all()


def test_adjust_without_markings_shifts_by_default_width() -> None:
    out = adjust_goals(np.array([[100.0, 0.0]]), np.zeros((1, 2)), 0.0, -1.0, np.full((1, 4), np.nan))
    np.testing.assert_allclose(out, [[120.0, W]])
