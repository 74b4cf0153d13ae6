"""``mobil`` goals: an IDM driver's endpoint, with MOBIL's lane choice (politeness 0)."""

from __future__ import annotations

import numpy as np
import pytest

from letspi.constants import DT_S, HORIZON_S
from letspi.physics.idm import CAR_IDM, IdmKernel
from letspi.physics.mobil import MobilGoalPredictor, lane_gaps
from letspi.scenario.build import LANE_WIDTH_M, VehicleSpec, straight_road_scenario
from letspi.scenario.types import concat_batches

MOBIL = MobilGoalPredictor()


def _goal(**kw: object) -> np.ndarray:
    return MOBIL.predict_goals(straight_road_scenario(n_lanes=3, ego_lane_index=1, **kw)).top[0]  # type: ignore[arg-type]


def test_behind_a_slow_leader_with_the_left_lane_free_the_goal_moves_one_lane_left() -> None:
    goal = _goal(ego_speed_mps=25.0, neighbours=[VehicleSpec(30.0, 15.0)])
    assert goal[1] == pytest.approx(LANE_WIDTH_M)  # left is +y; the right lane is as free: ties go left
    # in the free lane the ego keeps its (history's) desired speed of 25 m/s for the whole horizon
    assert goal[0] == pytest.approx(25.0 * HORIZON_S, rel=1e-6)


def test_a_fast_car_close_behind_in_the_left_lane_keeps_the_ego_out_of_it() -> None:
    slow = VehicleSpec(30.0, 15.0)
    closing = VehicleSpec(-8.0, 33.0, lane_offset=1)
    goal = MOBIL.predict_goals(straight_road_scenario(n_lanes=2, ego_lane_index=0, ego_speed_mps=25.0,
                                                      neighbours=[slow, closing])).top[0]
    assert goal[1] == pytest.approx(0.0)
    # the same car 60 m back imposes less than 2 m/s^2: the change is taken
    far = VehicleSpec(-60.0, 27.0, lane_offset=1)
    goal = MOBIL.predict_goals(straight_road_scenario(n_lanes=2, ego_lane_index=0, ego_speed_mps=25.0,
                                                      neighbours=[slow, far])).top[0]
    assert goal[1] == pytest.approx(LANE_WIDTH_M)


def test_a_gain_under_the_threshold_keeps_the_lane_and_the_goal_is_the_idm_endpoint() -> None:
    leader = VehicleSpec(120.0, 24.5)  # barely slower and far: the left lane gains < 0.2 m/s^2
    batch = straight_road_scenario(n_lanes=2, ego_lane_index=0, ego_speed_mps=25.0, neighbours=[leader])
    goal = MOBIL.predict_goals(batch).top[0]
    assert goal[1] == pytest.approx(0.0)
    # hand-rolled IDM behind a constant-speed leader, trapezoidal distance
    idm, v, gap, x = IdmKernel(np.array([25.0]), CAR_IDM), np.array([25.0]), np.array([120.0 - 4.5]), 0.0
    for _ in range(round(HORIZON_S / DT_S)):
        v_next = np.maximum(v + idm(v, gap, np.array([24.5])) * DT_S, 0.0)
        step = float(0.5 * (v + v_next)[0] * DT_S)
        x, gap, v = x + step, gap + 24.5 * DT_S - step, v_next
    assert goal[0] == pytest.approx(x)


def test_the_speed_limit_is_the_desired_speed_where_there_is_one() -> None:
    batch = straight_road_scenario(ego_speed_mps=20.0)
    free = MOBIL.predict_goals(batch).top[0, 0]
    assert free == pytest.approx(20.0 * HORIZON_S)
    batch.speed_limit_mps[:] = 30.0
    faster = MOBIL.predict_goals(batch).top[0, 0]
    assert 20.0 * HORIZON_S + 5.0 < faster < 30.0 * HORIZON_S


def test_a_lane_change_under_way_is_kept() -> None:
    batch = straight_road_scenario(n_lanes=3, ego_lane_index=1, ego_speed_mps=25.0)
    batch.ego_vxy_mps[:, :, 1] = -1.5  # drifting right: 2.25 m in the lookahead, past the marking 1.875 m away
    assert MOBIL.choose_lanes(batch)[0] == 0
    assert MOBIL.predict_goals(batch).top[0, 1] == pytest.approx(-LANE_WIDTH_M)


def test_lane_gaps_are_bumper_gaps_and_scenarios_are_independent_in_a_batch() -> None:
    a = straight_road_scenario(neighbours=[VehicleSpec(30.0, 15.0), VehicleSpec(-20.0, 26.0)])
    b = straight_road_scenario(neighbours=[VehicleSpec(40.0, 15.0, lane_offset=1)])
    gaps = lane_gaps(concat_batches([a, b]), np.array([1, 1]))
    np.testing.assert_allclose(gaps.lead_gap_m, [30.0 - 4.5, np.inf])
    np.testing.assert_allclose(gaps.follow_gap_m, [20.0 - 4.5, np.inf])
    np.testing.assert_allclose(gaps.lead_speed_mps, [15.0, np.nan])
    lanes = MOBIL.choose_lanes(concat_batches([a, b]))
    assert lanes.tolist()[1] == 1  # nothing ahead in its own lane: no reason to move


def test_sf_with_mobil_goals_plans_from_the_history_alone_and_has_its_own_key() -> None:
    from letspi.assembly.planners import build_planners
    from letspi.planners.options import PlannerOptions

    batch = straight_road_scenario(ego_speed_mps=25.0, neighbours=[VehicleSpec(30.0, 15.0)])
    history_only = MOBIL.predict_goals(batch.history()).goals_xy_m
    np.testing.assert_array_equal(MOBIL.predict_goals(batch).goals_xy_m, history_only)
    mobil, kinematic = (build_planners(["sf"], PlannerOptions(goals=g))[0] for g in ("mobil", "kinematic"))
    assert not mobil.reads_future and mobil.config.key() != kinematic.config.key()
    plan = mobil.planner.plan(batch.history())
    assert plan.goals_xy_m[0, 1] == pytest.approx(LANE_WIDTH_M) and plan.xy_m[0, -1, 1] > 0.5  # heading left
