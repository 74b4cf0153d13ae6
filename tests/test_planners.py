"""Physical behaviour of the baseline planners on hand-built scenarios."""

from __future__ import annotations

import numpy as np
import pytest

from letspi.assembly.planners import build_planners
from letspi.metrics.compute import compute_metrics
from letspi.physics.params import SocialForceParams
from letspi.planners.options import PlannerOptions
from letspi.planners.sf import SocialForcePlanner
from letspi.planners.sf_opt import SocialForceSearchPlanner
from letspi.planners.sf_params import load_sf_params, save_sf_params
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.split import split_by_vehicle, subsample
from letspi.scenario.types import concat_batches

BASELINE_PLANNERS = ("human", "cv", "idm", "sf", "sf-opt", "gnp")


def make_planner(kind, options=None):
    return build_planners([kind], options or PlannerOptions())[0].planner


def _closing_on_slower_leader():
    # ego at 32 m/s, a 22 m/s leader 40 m ahead in the same lane: constant-speed goal runs into it
    return straight_road_scenario(ego_speed_mps=32.0, neighbours=[VehicleSpec(x0_m=40.0, speed_mps=22.0)])


def test_fitted_sf_keeps_a_gap_while_absurd_parameters_collide():
    batch = _closing_on_slower_leader()
    fitted, _ = load_sf_params()
    ok = SocialForcePlanner(params=fitted).plan(batch)
    bad = SocialForcePlanner(params=SocialForceParams(k_np=0.0, k_nl=0.0)).plan(batch)
    m_ok = compute_metrics(batch, ok.xy_m, ok.vxy_mps, ok.goals_xy_m)
    m_bad = compute_metrics(batch, bad.xy_m, bad.vxy_mps, bad.goals_xy_m)
    assert not m_ok.collision[0] and m_ok.min_box_gap_m[0] > 1.0
    assert m_bad.collision[0]


def test_sf_opt_finds_a_safe_candidate_where_the_neutral_plan_is_unsafe():
    batch = _closing_on_slower_leader()
    weak = SocialForceParams(k_np=2.0)
    neutral = SocialForcePlanner(params=weak).plan(batch)
    assert compute_metrics(batch, neutral.xy_m, neutral.vxy_mps).collision[0]
    searched = SocialForceSearchPlanner(params=weak).plan(batch)
    m = compute_metrics(batch, searched.xy_m, searched.vxy_mps, searched.goals_xy_m)
    assert bool(searched.info["found_safe"][0])
    assert not m.collision[0] and m.min_ttc_s[0] >= 1.5
    # the choice is not the neutral candidate: stronger repulsion, a shorter goal or another lane
    chosen = (searched.info["k_scale"][0], searched.info["lon_factor"][0], searched.info["lane_factor"][0])
    assert chosen != (1.0, 0.4, 0.0)


def test_sf_opt_keeps_the_neutral_plan_on_a_free_road():
    batch = straight_road_scenario(ego_speed_mps=30.0)
    plan = SocialForceSearchPlanner(params=load_sf_params()[0]).plan(batch)
    assert plan.info["k_scale"][0] == 1.0 and plan.info["lon_factor"][0] == 0.4 and plan.info["lane_factor"][0] == 0


@pytest.mark.parametrize("name", BASELINE_PLANNERS)
def test_every_baseline_plans_finite_trajectories(name):
    batch = concat_batches([
        _closing_on_slower_leader(),
        straight_road_scenario(ego_speed_mps=0.0),  # standing still
        straight_road_scenario(n_lanes=2, ego_lane_index=0, neighbours=[VehicleSpec(-3.0, 30.0)]),
    ])
    built = build_planners([name], PlannerOptions())[0]
    plan = built.planner.plan(batch if built.reads_future else batch.history())
    assert plan.xy_m.shape == (3, 125, 2) and np.isfinite(plan.xy_m).all() and np.isfinite(plan.vxy_mps).all()


def test_unknown_planner_lists_the_valid_ones():
    with pytest.raises(ValueError, match="unknown planner 'magic' \\(available: human, cv, idm, sf, sf-opt"):
        make_planner("magic")


def test_sf_params_file_round_trip_and_errors(tmp_path):
    p = SocialForceParams(tau_s=1.3, k_np=22.0)
    path = save_sf_params(tmp_path / "p.json", p, {"data": "x"}, {"j": 1.0})
    loaded, record = load_sf_params(path)
    assert loaded == p and record["provenance"] == {"data": "x"}
    make_planner("sf", PlannerOptions(sf_params_file=path))
    (tmp_path / "bad.json").write_text('{"params": {"tau_s": 1}}')
    with pytest.raises(ValueError, match=r"bad.json: not a valid SF parameter file \(missing parameter"):
        load_sf_params(tmp_path / "bad.json")
    with pytest.raises(FileNotFoundError, match="no such SF parameter file"):
        load_sf_params(tmp_path / "none.json")


def test_split_by_vehicle_never_shares_a_vehicle():
    scen = [straight_road_scenario(scenario_id=f"s{i}") for i in range(12)]
    batch = concat_batches(scen)
    batch.ego_id[:] = np.repeat(np.arange(4), 3)  # 4 vehicles x 3 windows
    train, val = split_by_vehicle(batch, 0.5, seed=3)
    assert set(batch.ego_id[train]).isdisjoint(set(batch.ego_id[val]))
    assert len(train) + len(val) == 12


def test_subsample_keeps_few_indices_and_draws_an_ascending_subset_of_many():
    idx = np.array([2, 5, 7, 11, 13])
    assert subsample(idx, None, np.random.default_rng(0)) is idx
    assert subsample(idx, 5, np.random.default_rng(0)) is idx
    drawn = subsample(idx, 3, np.random.default_rng(4))
    assert len(drawn) == 3 and set(drawn) <= set(idx) and list(drawn) == sorted(drawn)
    assert np.array_equal(drawn, subsample(idx, 3, np.random.default_rng(4)))  # a seed gives the same rows


def test_fit_is_deterministic_and_not_worse_than_its_start():
    pytest.importorskip("letspi_train", reason="letspi-train is not installed (pip install -e packages/letspi-train)")
    from letspi_train.fitting.sf import fit_sf_params

    batch = concat_batches([_closing_on_slower_leader()] * 3 + [straight_road_scenario()] * 3)
    batch.ego_id[:] = np.arange(6)
    a = fit_sf_params(batch, seed=1, max_evaluations=25)
    b = fit_sf_params(batch, seed=1, max_evaluations=25)
    assert a.params == b.params
    assert a.train_objective <= a.start_objective + 1e-12


def test_idm_planner_settles_a_lane_change_smoothly():
    from letspi.constants import T0_INDEX
    from letspi.planners.idm import IdmPlanner

    s = straight_road_scenario(ego_speed_mps=30.0)
    # mid-lane-change at t = 0: 0.8 m left of centre, moving left at 1.0 m/s
    s.ego_xy_m[0, T0_INDEX, 1] = 0.8
    s.ego_vxy_mps[0, T0_INDEX, 1] = 1.0
    batch = s
    plan = IdmPlanner().plan(batch)
    m = compute_metrics(batch, plan.xy_m, plan.vxy_mps, plan.goals_xy_m)
    assert plan.xy_m[0, -1, 1] == pytest.approx(3.75, abs=0.05)  # ends at the left lane's centre
    assert m.peak_abs_acc_lat_mps2[0] < 4.0 and bool(m.success_self[0])  # the recorded human kept its lane


def test_safety_check_sees_a_faster_car_closing_from_behind():
    from letspi.physics.neighbours import predict_neighbours
    from letspi.planners.cv import ConstantVelocityPlanner
    from letspi.safety.plan_check import check_plans

    # ego at 25 m/s, a 29 m/s car 30 m behind in the same lane; a side-by-side car in the next lane
    batch = straight_road_scenario(ego_speed_mps=25.0, neighbours=[
        VehicleSpec(x0_m=-30.0, speed_mps=29.0), VehicleSpec(x0_m=0.0, speed_mps=25.0, lane_offset=1)])
    plan = ConstantVelocityPlanner().plan(batch)
    check = check_plans(batch, plan.xy_m, plan.vxy_mps, predict_neighbours(batch, "constant_velocity"))
    gap0 = 30.0 - 4.5
    # closest at the horizon: (25.5 m - 4 m/s * 5 s) / 4 m/s = 1.375 s
    assert check.min_rear_ttc_s[0] == pytest.approx((gap0 - 20.0) / 4.0, abs=1e-6)
    assert check.min_rear_ttc_nbr[0] == 0 and check.min_rear_ttc_step[0] == 124
    assert np.isinf(check.min_ttc_s[0]) and not check.collision[0]
    # the adjacent-lane car is 1.95 m away box to box but not in the ego's path
    assert check.min_box_gap_m[0] == pytest.approx(1.95, abs=1e-3)
    assert check.min_path_gap_m[0] < gap0 and not check.safe(1.5, 2.0)[0]


def test_unknown_options_are_clear_errors():
    with pytest.raises(ValueError, match="unknown neighbour prediction 'cv' \\(available: constant_velocity, idm"):
        make_planner("idm", PlannerOptions(neighbour_mode="cv"))


def test_goal_source_option():
    from letspi.learned.goal_model import LearnedGoalPredictor
    from letspi.physics.goals import KinematicGoalPredictor

    assert isinstance(make_planner("sf").goal_predictor, LearnedGoalPredictor)  # type: ignore[attr-defined]
    assert isinstance(make_planner("sf", PlannerOptions(goals="kinematic")).goal_predictor,  # type: ignore[attr-defined]
                      KinematicGoalPredictor)
    with pytest.raises(ValueError, match="unknown goal source 'psychic'"):
        make_planner("sf", PlannerOptions(goals="psychic"))
    with pytest.raises(ValueError, match="gnp uses its learned goal predictor"):
        make_planner("gnp", PlannerOptions(goals="kinematic"))


NON_ORACLE = ("cv", "idm", "sf", "sf-opt", "gnp", "llm", "letspi-memory")


@pytest.mark.parametrize("kind", NON_ORACLE)
def test_non_oracle_planners_never_read_the_future(kind):
    """Blanking every frame after t = 0 (or cutting them off) leaves every non-oracle plan unchanged."""
    from dataclasses import replace

    batch = concat_batches([_closing_on_slower_leader(), straight_road_scenario(
        ego_speed_mps=27.0, neighbours=[VehicleSpec(-15.0, 31.0), VehicleSpec(10.0, 26.0, lane_offset=1)])])
    future = slice(75, None)
    blanked = replace(batch, **{name: getattr(batch, name).copy() for name in
                                ("ego_xy_m", "ego_vxy_mps", "ego_axy_mps2", "nbr_xy_m", "nbr_vxy_mps")})
    for name in ("ego_xy_m", "ego_vxy_mps", "ego_axy_mps2"):
        getattr(blanked, name)[:, future] = np.nan
    for name in ("nbr_xy_m", "nbr_vxy_mps"):
        getattr(blanked, name)[:, :, future] = np.nan
    options = PlannerOptions(llm="scripted:default", llm_cache=False)
    built = build_planners([kind], options)[0]
    planner = built.planner
    assert not built.reads_future
    if planner.batch_size == 1:  # LLM planners: one scenario per call
        batch, blanked = batch.take([0]), blanked.take([0])
    plans = [planner.plan(b) for b in (batch, blanked, batch.history())]
    for other in plans[1:]:
        np.testing.assert_array_equal(plans[0].xy_m, other.xy_m)
        np.testing.assert_array_equal(plans[0].goals_xy_m, other.goals_xy_m)


def test_oracle_options_are_declared():
    assert build_planners(["human"], PlannerOptions())[0].reads_future
    assert build_planners(["sf"], PlannerOptions(goals="oracle"))[0].reads_future
    assert build_planners(["idm"], PlannerOptions(neighbour_mode="ground_truth_oracle"))[0].reads_future
