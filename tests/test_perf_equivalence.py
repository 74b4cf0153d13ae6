"""Optimised paths give bit-identical results to the algorithms they replaced (issue 27, speed).

Each test runs the replaced algorithm (written out here, as it was) next to the optimised one on
crowded random scenes and asserts exact equality (``np.array_equal``, NaN = NaN): benchmark results
are byte-identical before and after, so any difference, even in the last bit, is a failure.
"""

from __future__ import annotations

from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from letspi.assembly.planners import build_planners
from letspi.constants import DT_S, N_FUTURE
from letspi.evaluation.harness import evaluate, load_planner_results
from letspi.metrics.distance import distances
from letspi.metrics.inputs import MetricInputs
from letspi.metrics.ttc import ttc_1d
from letspi.physics.goals import NEUTRAL_LON_FACTOR, adjust_goals
from letspi.physics.idm import (
    CAR_IDM,
    GAP_FLOOR_FRACTION,
    IDM_MIN_ACCEL_MPS2,
    MIN_DESIRED_SPEED_MPS,
    IdmKernel,
    IdmParams,
    desired_speed_from_history,
    idm_acceleration,
)
from letspi.physics.neighbours import _t0_state, idm_leaders, predict_idm, predict_neighbours
from letspi.physics.params import SocialForceParams
from letspi.physics.social_force import SocialForceScene, rollout_social_force
from letspi.physics.types import NeighbourPrediction
from letspi.planners.base import PlanBatch, Proposals
from letspi.planners.options import DEFAULT_OPTIONS
from letspi.planners.sf_opt import SocialForceSearchPlanner
from letspi.planners.sf_params import load_sf_params
from letspi.safety.plan_check import SafetyCheck, check_inputs, check_plans, predicted_inputs
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.store import save_scenarios
from letspi.scenario.types import ScenarioBatch, concat_batches


def crowded_scenes(n: int, seed: int = 0) -> ScenarioBatch:
    """``n`` scenes of 6 neighbours within 45 m of the ego in its lane and both adjacent ones, some
    overlapping it (contacts), at speeds 10-35 m/s: ties, contacts, lane changes and empty lanes occur."""
    rng = np.random.default_rng(seed)
    scenes = []
    for i in range(n):
        nbrs = [VehicleSpec(x0_m=float(rng.uniform(-45.0, 45.0)), speed_mps=float(rng.uniform(10.0, 35.0)),
                            lane_offset=int(rng.integers(-1, 2))) for _ in range(6)]
        scenes.append(straight_road_scenario(ego_speed_mps=float(rng.uniform(15.0, 35.0)), neighbours=nbrs,
                                             scenario_id=f"c{i:03d}"))
    return concat_batches(scenes)


def _assert_equal(a: object, b: object, name: str = "") -> None:
    for f in fields(a):  # type: ignore[arg-type]
        x, y = np.asarray(getattr(a, f.name)), np.asarray(getattr(b, f.name))
        assert x.shape == y.shape, (name, f.name)
        assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), (name, f.name)


def _old_check_inputs(batch: ScenarioBatch, inp: MetricInputs) -> SafetyCheck:
    """check_inputs before issue 27's speed work: the rear TTC on the scene mirrored in x, all distances."""
    from letspi.metrics.collision import boxes_overlap
    from letspi.metrics.kinematics import off_road
    from letspi.safety.plan_check import _min_path_gap_m

    flip = np.array([-1.0, 1.0])
    mirrored = replace(inp, ego_xy_m=inp.ego_xy_m * flip, ego_vxy_mps=inp.ego_vxy_mps * flip,
                       nbr_xy_m=inp.nbr_xy_m * flip, nbr_vxy_mps=inp.nbr_vxy_mps * flip)
    ttc, rear, dist = ttc_1d(inp), ttc_1d(mirrored), distances(inp)
    return SafetyCheck(
        min_ttc_s=ttc.min_ttc_s, min_ttc_step=ttc.min_ttc_step, min_ttc_nbr=ttc.min_ttc_nbr,
        min_rear_ttc_s=rear.min_ttc_s, min_rear_ttc_step=rear.min_ttc_step, min_rear_ttc_nbr=rear.min_ttc_nbr,
        min_box_gap_m=dist.min_box_gap_m, min_gap_step=dist.min_gap_step, min_gap_nbr=dist.min_gap_nbr,
        min_path_gap_m=_min_path_gap_m(inp), collision=np.asarray(boxes_overlap(inp).any(axis=(1, 2)), dtype=bool),
        off_road=off_road(inp.ego_xy_m[..., 1], inp.ego_width_m, batch.marking_y_m, batch.marking_is_edge),
    )


def _repeated(pred: NeighbourPrediction, rows: np.ndarray) -> NeighbourPrediction:
    return NeighbourPrediction(*(np.asarray(a)[rows] for a in pred))


@pytest.fixture(scope="module")
def scenes() -> ScenarioBatch:
    return crowded_scenes(24, seed=3)


def _candidate_plans(batch: ScenarioBatch, c: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``c`` plans per scenario (rows, xy, vxy): the constant-velocity plan plus random lateral and
    longitudinal drifts, so plans cross lanes, close in on leaders and touch neighbours."""
    rng = np.random.default_rng(seed)
    rows = np.repeat(np.arange(len(batch)), c)
    t = (np.arange(1, 126) * 0.04)[None, :]
    v0 = batch.ego_vxy0_mps[rows, 0].astype(np.float64)[:, None]
    accel = rng.uniform(-6.0, 3.0, (len(rows), 1))
    lat = rng.uniform(-1.5, 1.5, (len(rows), 1))
    x = batch.ego_xy0_m[rows, 0][:, None] + v0 * t + 0.5 * accel * t**2
    y = batch.ego_xy0_m[rows, 1][:, None] + lat * t
    vx = np.maximum(v0 + accel * t, 0.0)
    xy = np.stack([x, y], axis=-1)
    vxy = np.stack([vx, np.broadcast_to(lat, vx.shape)], axis=-1)
    return rows, xy, vxy


def test_checks_of_candidate_plans_match_the_mirrored_scene_and_repeated_batch(scenes: ScenarioBatch) -> None:
    """check_plans with ``rows`` (rear TTC from the shared geometry, box gaps only) equals the old check on
    a batch and a prediction repeated per candidate, with the rear TTC of the mirrored scene."""
    pred = predict_neighbours(scenes, "idm")
    rows, xy, vxy = _candidate_plans(scenes, 9, seed=1)
    new = check_plans(scenes, xy, vxy, pred, rows=rows)
    big = scenes.take(rows)
    old = _old_check_inputs(big, predicted_inputs(big, xy, vxy, _repeated(pred, rows)))
    _assert_equal(new, old, "check_plans")
    assert new.collision.any() and not new.collision.all()  # the scenes exercise contacts
    assert np.isfinite(new.min_rear_ttc_s).any() and np.isfinite(new.min_ttc_s).any()
    _assert_equal(check_inputs(big, predicted_inputs(big, xy, vxy, _repeated(pred, rows))), old, "check_inputs")


def test_scene_of_scenarios_taken_equals_scene_of_the_taken_batch(scenes: ScenarioBatch) -> None:
    pred = predict_neighbours(scenes, "idm")
    rows = np.repeat(np.arange(len(scenes)), 5)
    a = SocialForceScene.from_batch(scenes, pred).take(rows)
    b = SocialForceScene.from_batch(scenes.take(rows), _repeated(pred, rows))
    _assert_equal(a, b, "scene")
    for name, value in vars(a).items():  # NumPy may round exp differently on strided arrays
        assert value.flags.c_contiguous == vars(b)[name].flags.c_contiguous, name


def _old_sf_opt_simulate(planner: SocialForceSearchPlanner, batch: ScenarioBatch, goals: np.ndarray,
                         pred: NeighbourPrediction, proposals: Proposals) -> PlanBatch:
    """SocialForceSearchPlanner.simulate before issue 27's speed work: the whole batch repeated per candidate."""
    b, grid = len(batch), planner.space.grid()
    c = len(grid)
    rep = np.repeat(np.arange(b), c)
    big = batch.take(rep)
    k_scale, lon, lane = (np.tile(grid[:, i], b) for i in range(3))
    base = SocialForceParams.from_matrix(proposals.params.as_matrix()[rep])
    params = replace(base, k_np=base.k_np * k_scale, k_nf=base.k_nf * k_scale, k_nl=base.k_nl * k_scale)
    cand_goals = adjust_goals(goals[rep], big.ego_xy0_m.astype(np.float64), lon, lane, big.marking_y_m)
    big_pred = _repeated(pred, rep)
    roll = rollout_social_force(big, params.clamped(), cand_goals, big_pred)
    big_inp = predicted_inputs(big, roll.xy_m, roll.vxy_mps, big_pred)
    check = _old_check_inputs(big, big_inp)
    space = planner.space
    safe = check.safe(space.ttc_threshold_s, space.gap_threshold_m).reshape(b, c)
    cost = (np.abs(lon - NEUTRAL_LON_FACTOR) + space.lane_change_cost * np.abs(lane)
            + space.k_scale_cost * (k_scale - 1.0)).reshape(b, c)
    ttc = np.minimum(np.minimum(check.min_ttc_s, check.min_rear_ttc_s), space.ttc_cap_s).reshape(b, c)
    gap = np.nan_to_num(check.min_box_gap_m, nan=-1e9, posinf=1e9).reshape(b, c)
    score = -(1e6 * check.collision.reshape(b, c) + 1e3 * check.off_road.reshape(b, c)) + ttc + 0.01 * gap
    best = np.where(safe.any(axis=1), np.argmin(np.where(safe, cost, np.inf), axis=1), np.argmax(score, axis=1))
    pick = np.arange(b) * c + best
    return PlanBatch(xy_m=roll.xy_m[pick], vxy_mps=roll.vxy_mps[pick], goals_xy_m=cand_goals[pick],
                     info={"k_scale": k_scale[pick], "found_safe": safe.any(axis=1),
                           "n_safe_candidates": safe.sum(axis=1)})


def test_sf_opt_search_matches_the_search_on_the_repeated_batch(scenes: ScenarioBatch) -> None:
    planner = SocialForceSearchPlanner(params=load_sf_params()[0])
    context = planner.context(scenes)
    proposals = planner.propose(scenes, context)
    new = planner.simulate(scenes, context, proposals)
    old = _old_sf_opt_simulate(planner, scenes, context.goals_xy_m, context.neighbours, proposals)
    for name in ("xy_m", "vxy_mps", "goals_xy_m"):
        assert np.array_equal(getattr(new, name), getattr(old, name)), name
    for key, values in old.info.items():
        assert np.array_equal(new.info[key], values), key
    assert 0 < int(np.sum(new.info["found_safe"])) < len(scenes)  # both branches of the choice are taken


def _old_idm_acceleration(v: np.ndarray, v0: np.ndarray, gap: np.ndarray, v_lead: np.ndarray,
                          prm: IdmParams) -> np.ndarray:
    """idm_acceleration before issue 27's speed work (constants recomputed every call)."""
    v = np.maximum(np.asarray(v, dtype=np.float64), 0.0)
    v0 = np.maximum(np.asarray(v0, dtype=np.float64), MIN_DESIRED_SPEED_MPS)
    has_leader = np.isfinite(gap)
    v_lead = np.where(has_leader, np.asarray(v_lead, dtype=np.float64), v)
    a_max = np.asarray(prm.max_accel_mps2, dtype=np.float64)
    b = np.asarray(prm.comfort_decel_mps2, dtype=np.float64)
    s0 = np.asarray(prm.min_gap_m, dtype=np.float64)
    s_star = s0 + np.maximum(0.0, v * prm.time_headway_s + v * (v - v_lead) / (2.0 * np.sqrt(a_max * b)))
    s = np.maximum(np.where(has_leader, gap, 1.0), GAP_FLOOR_FRACTION * s0)
    interaction = np.where(has_leader, (s_star / s) ** 2, 0.0)
    acc = a_max * (1.0 - (v / v0) ** prm.delta - interaction)
    return np.clip(acc, IDM_MIN_ACCEL_MPS2, a_max)


def _old_predict_idm(batch: ScenarioBatch) -> tuple[np.ndarray, np.ndarray]:
    """predict_idm's loop before issue 27's speed work (concatenate + take_along_axis per step): xs, vs."""
    xy0, vxy0, _ = _t0_state(batch)
    leader = idm_leaders(batch)
    has_leader = leader >= 0
    lead_idx = np.where(has_leader, leader, 0)
    hist = batch.history_slice
    v0 = desired_speed_from_history(batch.nbr_vxy_mps[:, :, hist, 0], batch.nbr_valid[:, :, hist])
    prm = IdmParams.for_classes(batch.nbr_class)
    nbr_len = np.nan_to_num(batch.nbr_length_m.astype(np.float64))
    cand_len = np.concatenate([nbr_len, batch.ego_length_m.astype(np.float64)[:, None]], axis=1)
    half_len = 0.5 * (nbr_len + np.take_along_axis(cand_len, lead_idx, axis=1))
    ego_x = np.nan_to_num(batch.ego_xy0_m[:, 0].astype(np.float64))
    ego_v = np.nan_to_num(batch.ego_vxy0_mps[:, 0].astype(np.float64))
    x, v = xy0[:, :, 0].copy(), np.maximum(vxy0[:, :, 0], 0.0)
    xs, vs = [], []
    for k in range(N_FUTURE):
        cand_x = np.concatenate([x, (ego_x + ego_v * (k * DT_S))[:, None]], axis=1)
        cand_v = np.concatenate([v, ego_v[:, None]], axis=1)
        gap = np.where(has_leader, np.take_along_axis(cand_x, lead_idx, axis=1) - x - half_len, np.inf)
        acc = _old_idm_acceleration(v, v0, gap, np.take_along_axis(cand_v, lead_idx, axis=1), prm)
        v = np.maximum(v + acc * DT_S, 0.0)
        x = x + v * DT_S
        xs.append(x)
        vs.append(v)
    return np.stack(xs, axis=2), np.stack(vs, axis=2)


def test_idm_prediction_matches_the_per_step_concatenating_loop(scenes: ScenarioBatch) -> None:
    pred = predict_idm(scenes)
    xs, vs = _old_predict_idm(scenes)
    ok = pred.valid
    assert np.array_equal(pred.xy_m[..., 0][ok], xs[ok]) and np.array_equal(pred.vxy_mps[..., 0][ok], vs[ok])
    assert (vs < vs[..., :1]).any()  # followers brake for their leaders


def test_idm_kernel_is_idm_acceleration_as_it_was() -> None:
    rng = np.random.default_rng(0)
    v, v0, v_lead = rng.uniform(0, 40, (3, 50, 7))
    gap = np.where(rng.random((50, 7)) < 0.2, np.inf, rng.uniform(-3, 80, (50, 7)))
    prm = IdmParams.for_classes(rng.integers(1, 3, (50, 7)))
    assert np.array_equal(IdmKernel(v0, prm)(v, gap, v_lead), _old_idm_acceleration(v, v0, gap, v_lead, prm))
    assert np.array_equal(idm_acceleration(v, v0, gap, v_lead), _old_idm_acceleration(v, v0, gap, v_lead, CAR_IDM))


@pytest.mark.slow
def test_open_loop_in_worker_processes_stores_the_same_rows(tmp_path: Path, scenes: ScenarioBatch) -> None:
    """``evaluate(..., workers=2)`` scores the batch planners in two spawned processes: same rows."""
    file = tmp_path / "scenes.arrow"
    save_scenarios(scenes, file)
    planners = build_planners(["cv", "sf", "sf-opt"], DEFAULT_OPTIONS)
    evaluate(planners, scenes, tmp_path / "one", scenarios_file=str(file))
    evaluate(planners, scenes, tmp_path / "two", scenarios_file=str(file), workers=2)
    for p in planners:
        a = load_planner_results(tmp_path / "one", p.name, with_plans=True).sort_values("row").reset_index(drop=True)
        b = load_planner_results(tmp_path / "two", p.name, with_plans=True).sort_values("row").reset_index(drop=True)
        a, b = (f.drop(columns=[c for c in f if c == "inference_s" or c.endswith("cpu_ms")]) for f in (a, b))
        pd.testing.assert_frame_equal(a, b, check_exact=True)
    assert (tmp_path / "two" / "metrics.json").exists() and (tmp_path / "two" / "run.json").exists()
