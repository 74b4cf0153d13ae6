"""Social force rollout: goal reaching, car following, force directions, lanes, guards, reference."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from benchmarks.physics import random_params, synthetic_batch
from benchmarks.sf_reference import rollout_social_force_reference
from letspi.constants import DT_S, N_FUTURE
from letspi.physics.neighbours import predict_constant_velocity
from letspi.physics.params import (
    DEFAULT_PARAMS,
    PARAM_NAMES,
    PARAM_RANGES,
    SocialForceParams,
)
from letspi.physics.social_force import (
    AX_MAX_MPS2,
    AX_MIN_MPS2,
    AY_MAX_MPS2,
    SocialForceScene,
    rollout_social_force,
    rollout_social_force_scene,
    social_force_terms,
)
from letspi.physics.types import RolloutResult
from letspi.scenario.build import LANE_WIDTH_M, VehicleSpec, straight_road_scenario
from letspi.scenario.types import ScenarioBatch


def _plan(
    batch: ScenarioBatch, goal_xy: tuple[float, float], params: SocialForceParams = DEFAULT_PARAMS
) -> RolloutResult:
    goals = np.tile(np.asarray(goal_xy, dtype=np.float64), (len(batch), 1))
    return rollout_social_force(batch, params, goals, predict_constant_velocity(batch))


def _leader_scene(k_np: float, *, gap_m: float = 60.0, ego_speed_mps: float = 35.0, horizon_s: float = 30.0):
    """1-D check: ego wants 35 m/s, leader at 25 m/s, ``gap_m`` bumper gap."""
    f = round(horizon_s / DT_S)
    length = 4.5
    lead_x = length + gap_m + 25.0 * np.arange(f + 1) * DT_S
    nbr_xy = np.zeros((1, 1, f + 1, 2))
    nbr_xy[0, 0, :, 0] = lead_x
    scene = SocialForceScene.from_arrays(
        ego_xy0_m=np.zeros((1, 2)),
        ego_vxy0_mps=np.array([[ego_speed_mps, 0.0]]),
        ego_length_m=np.array([length]),
        ego_width_m=np.array([1.8]),
        nbr_xy_m=nbr_xy,
        nbr_valid=np.ones((1, 1, f + 1), dtype=bool),
        nbr_length_m=np.array([[length]]),
        nbr_width_m=np.array([[1.8]]),
        marking_y_m=np.array([[-1.875, 1.875]]),
        marking_is_edge=np.array([[False, False]]),
    )
    params = SocialForceParams(tau_s=1.0, k_np=k_np, r_col_m=10.0)
    # goal far ahead + v0 capped at 35 m/s = a constant desired speed of 35 m/s
    res = rollout_social_force_scene(scene, params, np.array([[1e5, 0.0]]), max_speed_mps=35.0)
    gap = lead_x[1:] - res.xy_m[0, :, 0] - length
    return gap, res


# ---------------------------------------------------------------------------------------------
# goal reaching and car following


@pytest.mark.parametrize(("ego_speed", "goal_x"), [(30.0, 150.0), (25.0, 150.0), (30.0, 130.0)])
def test_free_road_reaches_goal(ego_speed: float, goal_x: float) -> None:
    batch = straight_road_scenario(ego_speed_mps=ego_speed)
    res = _plan(batch, (goal_x, 0.0))
    assert res.xy_m.shape == (1, N_FUTURE, 2)
    assert np.linalg.norm(res.xy_m[0, -1] - [goal_x, 0.0]) < 1.0


def test_on_schedule_free_road_is_steady() -> None:
    """A goal exactly at v * 5 s keeps the speed: no braking at the end of the plan."""
    batch = straight_road_scenario(ego_speed_mps=30.0)
    res = _plan(batch, (150.0, 0.0))
    assert np.allclose(res.vxy_mps[0, :, 0], 30.0, atol=1e-9)
    assert np.abs(res.axy_mps2).max() < 1e-9


@pytest.mark.parametrize(
    ("k_np", "steady_gap_m", "min_gap_range_m"),
    [(10.0, None, (-np.inf, 0.0)), (20.0, 10.0 * np.log(2.0), (4.5, 6.0)), (30.0, 10.0 * np.log(3.0), (8.5, 10.0))],
)
def test_one_dimensional_check(k_np: float, steady_gap_m: float | None, min_gap_range_m: tuple[float, float]) -> None:
    """Measured: k 10 collides (overlap 3.3 m), k 20 min 5.15 m / steady 6.93 m, k 30 min 9.2 / 10.99 m."""
    gap, res = _leader_scene(k_np)
    lo, hi = min_gap_range_m
    assert lo < gap.min() < hi
    if steady_gap_m is not None:
        assert gap[-1] == pytest.approx(steady_gap_m, abs=0.05)
        assert res.vxy_mps[0, -1, 0] == pytest.approx(25.0, abs=0.05)


def test_slower_leader_default_keeps_gap_absurd_collides() -> None:
    leader = VehicleSpec(x0_m=30.0, speed_mps=22.0)
    batch = straight_road_scenario(ego_speed_mps=32.0, neighbours=[leader])
    goal = (160.0, 0.0)  # the goal ignores the leader
    lead_x = 30.0 + 22.0 * DT_S * np.arange(1, N_FUTURE + 1)
    safe = _plan(batch, goal)
    gap_safe = lead_x - safe.xy_m[0, :, 0] - 4.5
    assert gap_safe.min() > 2.0
    reckless = _plan(batch, goal, SocialForceParams(k_np=0.0))
    gap_reckless = lead_x - reckless.xy_m[0, :, 0] - 4.5
    assert gap_reckless.min() < 0.0


# ---------------------------------------------------------------------------------------------
# force directions


def _terms_for(neighbours: list[VehicleSpec], ego_y: float = 0.0, ego_lane_index: int = 1, goal_y: float | None = None):
    batch = straight_road_scenario(ego_speed_mps=30.0, neighbours=neighbours, ego_lane_index=ego_lane_index)
    scene = SocialForceScene.from_batch(batch, predict_constant_velocity(batch))
    goal = np.array([[150.0, ego_y if goal_y is None else goal_y]])
    return social_force_terms(scene, DEFAULT_PARAMS, goal, np.array([[0.0, ego_y]]), np.array([[30.0, 0.0]]))


def test_preceding_pushes_back_following_pushes_forward() -> None:
    pre = _terms_for([VehicleSpec(x0_m=15.0, speed_mps=30.0)])
    assert pre.preceding[0, 0] < 0 and pre.preceding[0, 1] == 0
    assert pre.following[0, 0] == 0 and pre.lateral[0, 1] == 0
    fol = _terms_for([VehicleSpec(x0_m=-15.0, speed_mps=30.0)])
    assert fol.following[0, 0] > 0 and fol.preceding[0, 0] == 0


def test_preceding_magnitude_uses_bumper_gap() -> None:
    terms = _terms_for([VehicleSpec(x0_m=14.5, speed_mps=30.0)])  # 10 m bumper gap
    assert terms.preceding[0, 0] == pytest.approx(-DEFAULT_PARAMS.k_np * np.exp(-10.0 / DEFAULT_PARAMS.r_col_m))


def test_adjacent_lane_car_pushes_sideways_not_back() -> None:
    left_ahead = _terms_for([VehicleSpec(x0_m=5.0, speed_mps=30.0, lane_offset=1)])
    assert left_ahead.lateral[0, 1] < 0  # pushed right, away from it
    assert left_ahead.preceding[0, 0] == 0 and left_ahead.following[0, 0] == 0
    right = _terms_for([VehicleSpec(x0_m=0.0, speed_mps=30.0, lane_offset=-1)])
    assert right.lateral[0, 1] > 0


def test_two_lanes_away_exerts_nothing() -> None:
    batch_terms = _terms_for([VehicleSpec(x0_m=0.0, speed_mps=30.0, lane_offset=2)], ego_lane_index=0)
    assert np.all(batch_terms.neighbours == 0)


def test_lane_line_force_points_to_lane_centre() -> None:
    centre = _terms_for([])
    assert centre.lane[0, 1] == pytest.approx(0.0, abs=1e-12)
    left_of_centre = _terms_for([], ego_y=0.6)
    assert left_of_centre.lane_line[0, 1] < 0
    right_of_centre = _terms_for([], ego_y=-0.6)
    assert right_of_centre.lane_line[0, 1] > 0


def test_boundary_pushes_away_from_edge() -> None:
    # rightmost lane: the right road edge is 1.875 m below the lane centre
    near_right = _terms_for([], ego_y=-0.7, ego_lane_index=0)
    assert near_right.boundary[0, 1] > 0
    # leftmost lane, near the left edge
    near_left = _terms_for([], ego_y=0.7, ego_lane_index=2)
    assert near_left.boundary[0, 1] < 0
    # at the lane centre the shifted potential exerts nothing
    assert _terms_for([], ego_lane_index=0).boundary[0, 1] == 0.0
    # past the edge it still pushes back onto the road
    off_road = _terms_for([], ego_y=-2.5, ego_lane_index=0)
    assert off_road.boundary[0, 1] > 0


def test_clamped_total_within_limits() -> None:
    terms = _terms_for([VehicleSpec(x0_m=4.0, speed_mps=30.0)])  # overlapping boxes
    assert AX_MIN_MPS2 <= terms.clamped[0, 0] <= AX_MAX_MPS2
    assert terms.total[0, 0] < terms.clamped[0, 0] + 1e-12


# ---------------------------------------------------------------------------------------------
# lanes


@pytest.mark.parametrize("ego_lane_index", [0, 1, 2])
def test_lane_keeping_drift_small(ego_lane_index: int) -> None:
    batch = straight_road_scenario(ego_speed_mps=30.0, ego_lane_index=ego_lane_index)
    res = _plan(batch, (150.0, 0.0))
    assert np.abs(res.xy_m[0, :, 1]).max() < 0.3


def test_lane_keeping_with_neighbours_alongside() -> None:
    nbrs = [
        VehicleSpec(x0_m=0.0, speed_mps=30.0, lane_offset=1),
        VehicleSpec(x0_m=-20.0, speed_mps=30.0, lane_offset=-1),
    ]
    batch = straight_road_scenario(ego_speed_mps=30.0, neighbours=nbrs)
    res = _plan(batch, (150.0, 0.0))
    # the car alongside on the left nudges the ego right (measured 0.46 m with the defaults)
    assert res.xy_m[0, :, 1].max() < 0.05
    assert -0.6 < res.xy_m[0, :, 1].min() < -0.1


@pytest.mark.parametrize(("ego_lane_index", "direction"), [(1, 1), (1, -1), (0, 1), (2, -1)])
def test_lane_change_goes_through(ego_lane_index: int, direction: int) -> None:
    batch = straight_road_scenario(ego_speed_mps=30.0, ego_lane_index=ego_lane_index)
    target_y = direction * LANE_WIDTH_M
    res = _plan(batch, (150.0, target_y))
    assert abs(res.xy_m[0, -1, 1] - target_y) < 0.5
    assert np.abs(res.axy_mps2[0, :, 1]).max() <= AY_MAX_MPS2


def test_goal_off_road_is_not_followed() -> None:
    batch = straight_road_scenario(ego_speed_mps=30.0, ego_lane_index=0)
    res = _plan(batch, (150.0, -LANE_WIDTH_M))  # right of the right edge
    right_edge_y = -0.5 * LANE_WIDTH_M
    assert res.xy_m[0, :, 1].min() - 0.9 > right_edge_y  # the ego's side stays on the road


# ---------------------------------------------------------------------------------------------
# degenerate inputs


def _assert_sane(res: RolloutResult) -> None:
    for arr in (res.xy_m, res.vxy_mps, res.axy_mps2):
        assert np.isfinite(arr).all()
    assert (res.vxy_mps[..., 0] >= 0).all()
    assert (res.axy_mps2[..., 0] >= AX_MIN_MPS2 - 1e-9).all() and (res.axy_mps2[..., 0] <= AX_MAX_MPS2 + 1e-9).all()
    assert (np.abs(res.axy_mps2[..., 1]) <= AY_MAX_MPS2 + 1e-9).all()


def test_degenerate_inputs_stay_finite() -> None:
    batch = straight_road_scenario(
        ego_speed_mps=0.0,
        neighbours=[
            VehicleSpec(x0_m=0.0, speed_mps=0.0),  # boxes overlap at t = 0
            VehicleSpec(x0_m=2.0, speed_mps=0.0, lane_offset=1, y_offset_m=-1.9),  # overlaps laterally too
            VehicleSpec(x0_m=30.0, speed_mps=20.0, visible_from_index=150),  # not visible at t = 0
        ],
    )
    for goal in [(0.0, 0.0), (-50.0, 0.0), (-10.0, 30.0), (1e-12, 0.0), (5000.0, 0.0)]:
        _assert_sane(_plan(batch, goal))


def test_goal_behind_never_reverses() -> None:
    batch = straight_road_scenario(ego_speed_mps=20.0)
    res = _plan(batch, (-50.0, 0.0))
    _assert_sane(res)
    assert res.vxy_mps[0, -1, 0] < 0.5  # decays as exp(-t / tau) towards 0
    assert np.all(np.diff(res.vxy_mps[0, :, 0]) <= 0)
    assert np.all(np.diff(res.xy_m[0, :, 0]) >= 0)


def test_nan_neighbours_and_markings() -> None:
    batch = straight_road_scenario(ego_speed_mps=25.0, neighbours=[VehicleSpec(x0_m=20.0, speed_mps=20.0)])
    pred = predict_constant_velocity(batch)
    nan_pred = pred._replace(xy_m=np.full_like(pred.xy_m, np.nan))  # valid flags lie, positions are NaN
    no_markings = np.full_like(batch.marking_y_m, np.nan)
    scene = SocialForceScene.from_arrays(
        ego_xy0_m=batch.ego_xy0_m,
        ego_vxy0_mps=batch.ego_vxy0_mps,
        ego_length_m=batch.ego_length_m,
        ego_width_m=np.array([np.nan]),
        nbr_xy_m=np.concatenate([np.full((1, 8, 1, 2), np.nan), nan_pred.xy_m], axis=2),
        nbr_valid=np.ones((1, 8, N_FUTURE + 1), dtype=bool),
        nbr_length_m=batch.nbr_length_m,
        nbr_width_m=batch.nbr_width_m,
        marking_y_m=no_markings,
        marking_is_edge=batch.marking_is_edge,
    )
    res = rollout_social_force_scene(scene, DEFAULT_PARAMS, np.array([[125.0, 0.0]]))
    _assert_sane(res)
    assert res.xy_m[0, -1, 0] == pytest.approx(125.0, abs=1.0)


def test_non_finite_goal_rejected() -> None:
    batch = straight_road_scenario()
    with pytest.raises(ValueError, match="finite"):
        _plan(batch, (np.nan, 0.0))


@settings(max_examples=25, deadline=None)
@given(
    ego_speed=st.floats(0.0, 45.0),
    nbr_x=st.floats(-20.0, 20.0),
    nbr_speed=st.floats(0.0, 45.0),
    lane_offset=st.integers(-1, 1),
    goal_x=st.floats(-100.0, 300.0),
    goal_y=st.floats(-10.0, 10.0),
    k_np=st.floats(*PARAM_RANGES["k_np"]),
    tau=st.floats(*PARAM_RANGES["tau_s"]),
)
def test_random_inputs_stay_finite_and_plausible(
    ego_speed: float, nbr_x: float, nbr_speed: float, lane_offset: int, goal_x: float, goal_y: float, k_np: float,
    tau: float,
) -> None:
    batch = straight_road_scenario(
        ego_speed_mps=ego_speed, neighbours=[VehicleSpec(x0_m=nbr_x, speed_mps=nbr_speed, lane_offset=lane_offset)]
    )
    _assert_sane(_plan(batch, (goal_x, goal_y), SocialForceParams(k_np=k_np, tau_s=tau)))


# ---------------------------------------------------------------------------------------------
# batched vs scalar reference, parameters


def test_batched_matches_reference_loop() -> None:
    rng = np.random.default_rng(7)
    n = 24
    batch = synthetic_batch(n, seed=3, n_distinct=n)
    params = random_params(n, rng)
    goals = np.stack([rng.uniform(50.0, 200.0, n), rng.uniform(-4.0, 4.0, n)], axis=1)
    scene = SocialForceScene.from_batch(batch, predict_constant_velocity(batch))
    fast = rollout_social_force_scene(scene, params, goals)
    slow = rollout_social_force_reference(scene, params, goals)
    for a, b in ((fast.xy_m, slow.xy_m), (fast.vxy_mps, slow.vxy_mps), (fast.axy_mps2, slow.axy_mps2)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)
    # the random scenarios do interact (otherwise the comparison proves little)
    free = rollout_social_force_scene(scene, SocialForceParams.from_matrix(
        np.where(np.isin(np.arange(7), [1, 2, 3]), 0.0, params.as_matrix())), goals)
    assert np.abs(free.xy_m - fast.xy_m).max() > 1.0


def test_params_clamp_and_matrix_roundtrip() -> None:
    wild = SocialForceParams(tau_s=0.0, k_np=1e6, k_nf=-3.0, k_nl=float("nan"), r_col_m=1e9)
    c = wild.clamped()
    for name in PARAM_NAMES:
        lo, hi = PARAM_RANGES[name]
        assert lo <= getattr(c, name) <= hi
    assert c.k_nl == DEFAULT_PARAMS.k_nl
    batch = SocialForceParams.stack([DEFAULT_PARAMS, wild])
    again = SocialForceParams.from_matrix(batch.as_matrix())
    assert again.row(0) == DEFAULT_PARAMS
    assert again.clamped().row(1) == c
    assert SocialForceParams.from_mapping({"k_np": 20}).k_np == 20.0
    with pytest.raises(KeyError):
        SocialForceParams.from_mapping({"bogus": 1.0})
    for name in PARAM_NAMES:
        lo, hi = PARAM_RANGES[name]
        assert lo <= getattr(DEFAULT_PARAMS, name) <= hi


def test_neighbour_weights_scale_each_neighbours_repulsion() -> None:
    from dataclasses import replace

    from letspi.physics.params import SocialForceParams
    from letspi.physics.social_force import SocialForceScene, rollout_social_force_scene

    batch = straight_road_scenario(ego_speed_mps=32.0, neighbours=[
        VehicleSpec(x0_m=40.0, speed_mps=22.0), VehicleSpec(x0_m=-15.0, speed_mps=34.0)])
    scene = SocialForceScene.from_batch(batch, predict_constant_velocity(batch))
    goals = np.array([[150.0, 0.0]])
    p = SocialForceParams()
    ones = rollout_social_force_scene(scene, p, goals, nbr_weights=np.ones((1, scene.n_neighbours)))
    plain = rollout_social_force_scene(scene, p, goals)
    np.testing.assert_array_equal(ones.xy_m, plain.xy_m)
    zero = rollout_social_force_scene(scene, p, goals, nbr_weights=np.zeros((1, scene.n_neighbours)))
    off = rollout_social_force_scene(scene, replace(p, k_np=0.0, k_nf=0.0, k_nl=0.0), goals)
    np.testing.assert_allclose(zero.xy_m, off.xy_m, atol=1e-12)
    doubled = rollout_social_force_scene(scene, p, goals, nbr_weights=np.full((1, scene.n_neighbours), 2.0))
    stronger = rollout_social_force_scene(scene, replace(p, k_np=2 * p.k_np, k_nf=2 * p.k_nf, k_nl=2 * p.k_nl), goals)
    np.testing.assert_allclose(doubled.xy_m, stronger.xy_m, atol=1e-9)
    with pytest.raises(ValueError, match="nbr_weights must be"):
        rollout_social_force_scene(scene, p, goals, nbr_weights=np.ones((2, 3)))
