"""The ``frenet`` lattice planner: polynomials, behaviour on hand-built scenarios, safety, batching."""

from __future__ import annotations

import numpy as np
import pytest

from letspi.bench.physics import synthetic_batch
from letspi.constants import DT_S, N_FUTURE
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.planners.frenet import (
    FrenetPlanner,
    FrenetSettings,
    FrenetWeights,
    evaluate_held,
    jerk_integral,
    load_frenet_weights,
    quartic_coefficients,
    quintic_coefficients,
    save_frenet_weights,
)
from letspi.safety.plan_check import check_plans
from letspi.scenario.build import LANE_WIDTH_M, VehicleSpec, straight_road_scenario
from letspi.scenario.types import concat_batches


def _numeric_derivatives(c, t):
    p = np.polynomial.polynomial.Polynomial(c)
    return p(t), p.deriv(1)(t), p.deriv(2)(t), p.deriv(3)


def test_quintic_and_quartic_meet_their_boundary_conditions_and_the_jerk_integral_is_exact():
    t_end = np.array(3.7)
    c5 = quintic_coefficients(np.array(1.0), np.array(2.0), np.array(-0.5), np.array(4.0), np.array(0.3),
                              np.array(0.2), t_end)
    p, v, a, _ = _numeric_derivatives(c5, t_end)
    assert (p, v, a) == pytest.approx((4.0, 0.3, 0.2), abs=1e-9)
    assert _numeric_derivatives(c5, 0.0)[:3] == pytest.approx((1.0, 2.0, -0.5))
    c4 = quartic_coefficients(np.array(0.0), np.array(30.0), np.array(1.0), np.array(25.0), np.array(0.0), t_end)
    assert c4[5] == 0.0
    _, v4, a4, _ = _numeric_derivatives(c4, t_end)
    assert (v4, a4) == pytest.approx((25.0, 0.0), abs=1e-9)
    grid = np.linspace(0.0, float(t_end), 200_001)
    for c in (c5, c4):
        j = _numeric_derivatives(c, 0.0)[3](grid)
        assert jerk_integral(c, t_end) == pytest.approx(np.trapezoid(j**2, grid), rel=1e-6)


def test_held_evaluation_extends_with_constant_speed_after_the_horizon():
    c = quartic_coefficients(np.array([0.0]), np.array([20.0]), np.array([0.0]), np.array([25.0]), np.array([0.0]),
                             np.array([3.0]))
    t = np.arange(1, N_FUTURE + 1) * DT_S
    p, v, a = evaluate_held(c, np.array([3.0]), t)
    after = t > 3.0
    assert np.allclose(v[0, after], 25.0) and np.allclose(a[0, after], 0.0)
    # positions continue linearly from the end state: the speed integrates to the positions
    assert np.allclose(np.diff(p[0, after]), 25.0 * DT_S)


def _lead_and_neighbours(adjacent):
    leader = VehicleSpec(x0_m=45.0, speed_mps=20.0)
    return [leader, *adjacent]


def _gap_to(plan_xy, batch, slot):
    """Bumper-to-bumper gap (F,) between the plan and the recorded future of neighbour ``slot``."""
    fut = batch.future_slice
    nx = batch.nbr_xy_m[0, slot, fut, 0]
    half = 0.5 * (batch.ego_length_m[0] + batch.nbr_length_m[0, slot])
    return nx - plan_xy[0, :, 0] - half


def test_keeps_its_lane_behind_a_slower_leader_at_a_safe_gap_when_the_other_lane_is_as_slow():
    # two lanes; the left one is a platoon at the leader's speed: nothing to gain by changing
    platoon = [VehicleSpec(x0_m=x, speed_mps=20.0, lane_offset=1) for x in (-30.0, -5.0, 20.0, 45.0, 70.0)]
    batch = straight_road_scenario(ego_speed_mps=30.0, neighbours=_lead_and_neighbours(platoon), n_lanes=2,
                                   ego_lane_index=0)
    plan = FrenetPlanner().plan(batch.history())
    assert plan.info["target_lane"][0] == 0 and plan.info["found_safe"][0]
    assert np.abs(plan.xy_m[0, :, 1]).max() < 0.5 * LANE_WIDTH_M - 0.5 * batch.ego_width_m[0]
    gap = _gap_to(plan.xy_m, batch, 0)
    assert gap.min() >= 2.0  # the safety check's front gap
    # it settles behind the leader: slower than 23 m/s at the end (started at 30, leader at 20)
    assert plan.vxy_mps[0, -1, 0] < 23.0


@pytest.mark.parametrize(("leader_x_m", "leader_mps", "weights"), [(120.0, 5.0, None), (45.0, 20.0, FrenetWeights())])
def test_overtakes_when_the_adjacent_lane_is_free(leader_x_m, leader_mps, weights):
    # the fitted (shipped) weights price a lane change high (lateral jerk): they pass a 5 m/s leader but follow
    # a 10-20 m/s one; the hand-set starting weights also pass a 20 m/s leader
    right_platoon = [VehicleSpec(x0_m=x, speed_mps=leader_mps, lane_offset=-1) for x in (-20.0, 5.0, 30.0, 55.0)]
    leader = VehicleSpec(x0_m=leader_x_m, speed_mps=leader_mps)
    batch = straight_road_scenario(ego_speed_mps=30.0, neighbours=[leader, *right_platoon], n_lanes=3,
                                   ego_lane_index=1)
    planner = FrenetPlanner() if weights is None else FrenetPlanner(settings=FrenetSettings(weights=weights))
    plan = planner.plan(batch.history())
    assert plan.info["target_lane"][0] == 1 and plan.info["found_safe"][0]
    assert plan.xy_m[0, -1, 1] > 0.5 * LANE_WIDTH_M  # ends in the left lane
    assert plan.xy_m[0, -1, 0] > leader_x_m + leader_mps * 5.0  # passed the leader
    check = check_plans(batch, plan.xy_m, plan.vxy_mps, predict_neighbours(batch.history(), "idm"))
    assert not check.collision[0]


def test_never_chooses_a_colliding_candidate_when_a_safe_one_exists():
    batch = synthetic_batch(160, seed=11).history()
    planner = FrenetPlanner()
    lattice = planner.lattice(batch)
    plan = planner.plan(batch)
    i, j, _, n_valid = lattice.choose(planner.settings.weights)
    rows = np.arange(len(batch))
    safe_exists = n_valid > 0
    assert 0 < safe_exists.sum() < len(batch)  # both cases occur in this sample
    assert (lattice.violation[rows, i, j][safe_exists] == 0).all()
    assert (lattice.contact[rows, i, j][safe_exists] == 0).all()
    # the independent check (letspi.safety, the same prediction) agrees: no contact, on the road
    check = check_plans(batch, plan.xy_m, plan.vxy_mps, predict_neighbours(batch, NeighbourPredictionMode.IDM))
    assert not check.collision[safe_exists].any() and not check.off_road[safe_exists].any()
    # without a safe candidate: the least-contact one among those that exist
    unsafe = ~safe_exists
    best = np.where(lattice.pair_ok, lattice.contact, np.inf).reshape(len(batch), -1).min(axis=1)
    assert np.array_equal(lattice.contact[rows, i, j][unsafe], best[unsafe])


def test_a_cheaper_colliding_candidate_loses_to_a_safe_one():
    # a stopped car 100 m ahead in the ego's lane: holding speed is cheapest and collides
    batch = straight_road_scenario(ego_speed_mps=25.0, neighbours=[VehicleSpec(x0_m=100.0, speed_mps=0.0)],
                                   n_lanes=1, ego_lane_index=0)
    planner = FrenetPlanner()
    lattice = planner.lattice(batch.history())
    w = planner.settings.weights
    cost = lattice.cost(w)[0]
    cheapest = np.unravel_index(np.argmin(cost), cost.shape)
    assert lattice.contact[0][cheapest] > 0
    plan = planner.plan(batch.history())
    assert plan.info["found_safe"][0]
    gap = _gap_to(plan.xy_m, batch, 0)
    assert gap.min() > 0.0 and plan.vxy_mps[0, -1, 0] < 1.0


def test_batched_plans_equal_a_per_scenario_loop():
    batch = synthetic_batch(48, seed=5).history()
    planner = FrenetPlanner()
    together = planner.plan(batch)
    alone = [planner.plan(batch.take([k])) for k in range(len(batch))]
    # the same candidate everywhere; numbers equal to float rounding (a batch pads its lane markings)
    for key in ("target_lane", "lateral_offset_m", "lateral_horizon_s", "lon_mode", "lon_horizon_s", "n_safe",
                "found_safe"):
        assert np.array_equal(np.concatenate([p.info[key] for p in alone]), together.info[key]), key
    for key in ("target_speed_mps", "cost"):
        assert np.allclose(np.concatenate([p.info[key] for p in alone]), together.info[key], rtol=1e-12), key
    assert np.abs(np.concatenate([p.xy_m for p in alone]) - together.xy_m).max() < 1e-9
    assert np.abs(np.concatenate([p.vxy_mps for p in alone]) - together.vxy_mps).max() < 1e-9


def test_plans_are_continuous_with_the_t0_state_and_within_the_limits():
    batch = concat_batches([straight_road_scenario(ego_speed_mps=v, ego_accel_mps2=a) for v, a in
                            ((30.0, 0.0), (20.0, 1.0), (35.0, -2.0))])
    plan = FrenetPlanner().plan(batch.history())
    v0 = batch.ego_vxy0_mps.astype(np.float64)
    first_acc = (plan.vxy_mps[:, 0] - v0) / DT_S
    assert np.abs(first_acc[:, 0] - batch.ego_axy_mps2[:, 74, 0]).max() < 0.5
    acc = np.diff(plan.vxy_mps, axis=1) / DT_S
    limits = FrenetPlanner().settings.limits
    assert acc[..., 0].max() <= limits.max_accel_mps2 + 1e-6 and acc[..., 0].min() >= -limits.max_decel_mps2 - 1e-6
    assert np.abs(acc[..., 1]).max() <= limits.max_lat_accel_mps2 + 1e-6
    # positions integrate the velocities (trapezoid rule to 1 mm)
    xy = np.concatenate([batch.ego_xy0_m[:, None].astype(np.float64), plan.xy_m], axis=1)
    v = np.concatenate([v0[:, None], plan.vxy_mps], axis=1)
    assert np.abs(np.diff(xy, axis=1) - 0.5 * DT_S * (v[:, 1:] + v[:, :-1])).max() < 1e-3


def test_weights_round_trip_and_reject_a_bad_file(tmp_path):
    shipped, record = load_frenet_weights()
    assert isinstance(shipped, FrenetWeights) and "provenance" in record
    w = FrenetWeights(k_jerk_lon=0.3, k_goal_lane=4.0)
    path = save_frenet_weights(tmp_path / "w.json", w, {"seed": 1}, {"train_objective": 1.0})
    assert load_frenet_weights(path)[0] == w
    (tmp_path / "bad.json").write_text('{"weights": {"k_jerk": 1}}')
    with pytest.raises(ValueError, match="not a valid frenet weights file"):
        load_frenet_weights(tmp_path / "bad.json")
    with pytest.raises(FileNotFoundError, match="letspi fit frenet"):
        load_frenet_weights(tmp_path / "missing.json")
