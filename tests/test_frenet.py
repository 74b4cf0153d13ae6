"""The ``frenet`` lattice planner: polynomials, behaviour on hand-built scenarios, safety, batching."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.physics import synthetic_batch
from letspi.constants import DT_S, N_FUTURE
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.planners.frenet import (
    LON_BRAKE,
    LON_SPEED,
    FrenetFollowing,
    FrenetPlanner,
    FrenetSafety,
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


@pytest.mark.parametrize(("leader_x_m", "leader_mps"), [(120.0, 5.0), (45.0, 20.0)])
def test_overtakes_when_the_adjacent_lane_is_free(leader_x_m, leader_mps):
    # with the hand-set starting weights (FrenetWeights()); the fitted (shipped) ones price a lane change's
    # lateral jerk high (k_jerk_lat 30: ~97 for the gentlest change) and, behind the 5 m/s leader 120 m ahead,
    # prefer braking at 3 m/s² (~63: mean-speed deficit, onset jerk, RSS deficit)
    weights = FrenetWeights()
    right_platoon = [VehicleSpec(x0_m=x, speed_mps=leader_mps, lane_offset=-1) for x in (-20.0, 5.0, 30.0, 55.0)]
    leader = VehicleSpec(x0_m=leader_x_m, speed_mps=leader_mps)
    batch = straight_road_scenario(ego_speed_mps=30.0, neighbours=[leader, *right_platoon], n_lanes=3,
                                   ego_lane_index=1)
    plan = FrenetPlanner(settings=FrenetSettings(weights=weights)).plan(batch.history())
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
    assert (lattice.pairs.violation[rows, i, j][safe_exists] == 0).all()
    assert (lattice.pairs.contact[rows, i, j][safe_exists] == 0).all()
    # the independent check (letspi.safety, the same prediction) agrees: no contact, on the road
    check = check_plans(batch, plan.xy_m, plan.vxy_mps, predict_neighbours(batch, NeighbourPredictionMode.IDM))
    assert not check.collision[safe_exists].any() and not check.off_road[safe_exists].any()
    # without a safe candidate: the least unsafe one among those that exist (latest first contact, a lane
    # change into an occupied lane counting earlier); the penalty applies to lane changes only
    unsafe = ~safe_exists
    best = np.where(lattice.pairs.ok, lattice.pairs.unsafe_rank, np.inf).reshape(len(batch), -1).min(axis=1)
    assert np.array_equal(lattice.pairs.unsafe_rank[rows, i, j][unsafe], best[unsafe])
    assert not lattice.pairs.occupied[:, :, lattice.lat.lane == 0].any() and lattice.pairs.occupied.any()
    penalised = lattice.pairs.unsafe_rank - lattice.pairs.contact
    assert (penalised[lattice.pairs.occupied] > 0).all() and (penalised[~lattice.pairs.occupied] == 0).all()


def test_a_cheaper_colliding_candidate_loses_to_a_safe_one():
    # a stopped car 100 m ahead in the ego's lane: holding speed is cheapest and collides
    batch = straight_road_scenario(ego_speed_mps=25.0, neighbours=[VehicleSpec(x0_m=100.0, speed_mps=0.0)],
                                   n_lanes=1, ego_lane_index=0)
    planner = FrenetPlanner()
    lattice = planner.lattice(batch.history())
    w = planner.settings.weights
    cost = lattice.cost(w)[0]
    cheapest = np.unravel_index(np.argmin(cost), cost.shape)
    assert lattice.pairs.contact[0][cheapest] > 0
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


def _braking_leader(gap_m=12.0, speed_mps=14.0, decel_mps2=8.0):
    """One lane; a leader at the ego's speed that has been braking at ``decel_mps2`` and goes on to a stop."""
    leader = VehicleSpec(x0_m=gap_m + 4.5, speed_mps=speed_mps, accel_mps2=-decel_mps2)
    return straight_road_scenario(ego_speed_mps=speed_mps, neighbours=[leader], n_lanes=1, ego_lane_index=0)


def test_behind_a_leader_braking_hard_from_t0_it_brakes_and_keeps_a_gap():
    # the leader (14 m/s, 12 m ahead, braking at 8 m/s²) stops after 1.75 s and 12.25 m: only hard braking
    # from t = 0 keeps a gap. The shared IDM prediction lets the leader re-accelerate towards its history's
    # top speed (38 m/s); the cautious one extrapolates its braking.
    batch = _braking_leader()
    planner = FrenetPlanner()
    plan = planner.plan(batch.history())
    assert plan.info["found_safe"][0] and plan.info["lon_mode"][0] == LON_BRAKE
    gap = _gap_to(plan.xy_m, batch, 0)
    assert gap.min() >= 2.0  # against the recorded (braking) future, not only the prediction
    assert plan.vxy_mps[0, -1, 0] < 0.5
    # a braking candidate's jerk term is its step at t = 0 as a ramp over brake_onset_s: (a0 + d)² / onset
    lattice = planner.lattice(batch.history())
    brake = lattice.lon.mode == LON_BRAKE
    decels = np.array(planner.settings.sampling.brake_decels_mps2)
    assert np.allclose(lattice.lon.jerk[0, brake], decels**2 / planner.settings.sampling.brake_onset_s)
    # braking at d from 14 m/s stops after 14 / d s (the candidate's horizon) and 14² / (2 d) m
    assert np.allclose(lattice.lon.horizon_s[0, brake], np.minimum(14.0 / decels, 5.0))
    x_end = lattice.plans(np.flatnonzero(brake)[[2]], np.array([0]))[0][0, -1, 0]
    assert x_end == pytest.approx(14.0**2 / (2 * decels[2]), abs=1e-6)
    # without the cautious prediction and the following terms (the planner before them) it runs out of gap
    trusting = FrenetSettings(weights=planner.settings.weights.model_copy(update={"k_headway": 0.0, "k_rss": 0.0}),
                              safety=FrenetSafety(cautious_check=False))
    old = FrenetPlanner(settings=trusting).plan(batch.history())
    assert _gap_to(old.xy_m, batch, 0).min() < 2.0


def test_a_candidate_unsafe_under_the_cautious_prediction_is_not_picked_when_a_safe_one_exists():
    batch = _braking_leader().history()
    planner = FrenetPlanner()
    cautious = planner.lattice(batch)
    trusting = FrenetPlanner(settings=planner.settings.model_copy(
        update={"safety": FrenetSafety(cautious_check=False)})).lattice(batch)
    only_cautious = ((cautious.pairs.violation > 0) & (trusting.pairs.violation == 0) & cautious.pairs.ok
                     & cautious.pairs.feasible)
    assert only_cautious.any()  # pairs that only the cautious prediction marks as unsafe
    # the IDM check alone would take one of them (the cheapest pair clear of the IDM prediction)
    w = planner.settings.weights
    i_old, j_old, _, n_old = trusting.choose(w)
    assert n_old[0] > 0 and only_cautious[0, i_old[0], j_old[0]]
    i, j, _, n_valid = cautious.choose(w)
    assert n_valid[0] > 0 and cautious.pairs.violation[0, i[0], j[0]] == 0 and not only_cautious[0, i[0], j[0]]
    # the cautious check only adds unsafe pairs (never clears one the IDM check marks)
    assert not ((trusting.pairs.violation > 0) & (cautious.pairs.violation == 0)).any()


@pytest.mark.parametrize(("gap_m", "headway_levels", "rss_levels"), [(24.0, 1, 2), (16.0, 2, 2), (40.0, 0, 0)])
def test_following_terms_count_the_graded_deficit_of_the_gap(gap_m, headway_levels, rss_levels):
    # a leader at the ego's 20 m/s, gap_m bumper to bumper, held: desired distance 2 + 1.5 x 20 = 32 m, RSS
    # distance 2 + 20 x 0.5 + 20² / 8 - 20² / 16 = 37 m. Levels k / 3 above the gap ratio: 24 m -> 0.75 of
    # 32 (level 1) and 0.65 of 37 (levels 2/3, 1); 16 m -> 0.5 and 0.43 (2 and 2); 40 m: none. Each level
    # counts dt / 3 per frame over the 5 s plan.
    batch = straight_road_scenario(ego_speed_mps=20.0, neighbours=[VehicleSpec(x0_m=gap_m + 4.5, speed_mps=20.0)],
                                   n_lanes=1, ego_lane_index=0).history()
    settings = FrenetSettings(following=FrenetFollowing())
    lattice = FrenetPlanner(settings=settings).lattice(batch)
    held = ((lattice.lon.mode == LON_SPEED) & (np.abs(lattice.lon.target_speed_mps[0] - 20.0) < 1e-9)
            & (lattice.lon.jerk[0] < 1e-12))
    centre = (lattice.lat.lane == 0) & (lattice.lat.offset_m == 0.0)
    assert held.any() and centre.any()
    pairs = np.ix_(held, centre)
    assert np.allclose(lattice.pairs.headway_deficit_s[0][pairs], headway_levels * 5.0 / 3)
    assert np.allclose(lattice.pairs.rss_deficit_s[0][pairs], rss_levels * 5.0 / 3)
    # a candidate that drops back has a smaller deficit
    slower = lattice.lon.mean_speed_mps[0] < 17.0
    assert (lattice.pairs.rss_deficit_s[0][np.ix_(slower, centre)] <= rss_levels * 5.0 / 3).all()
