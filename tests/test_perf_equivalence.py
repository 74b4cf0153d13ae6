"""Optimised paths give bit-identical results to the algorithms they replaced (issue 27, speed).

Each test runs the replaced algorithm (kept as it was in ``benchmarks.replaced``, which
``python -m benchmarks.speed physics`` also times) next to the optimised one on crowded random scenes and asserts
exact equality (``np.array_equal``, NaN = NaN): benchmark results are byte-identical before and after,
so any difference, even in the last bit, is a failure.
"""

from __future__ import annotations

from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from benchmarks.replaced import (
    check_inputs_mirrored,
    idm_acceleration_per_call,
    predict_idm_concatenating,
    repeated,
    sf_check_checking_every_preset,
    sf_opt_all_candidates,
    sf_opt_on_repeated_batch,
)
from letspi.assembly.planners import build_planners
from letspi.evaluation.harness import EvaluationSettings, evaluate
from letspi.evaluation.results import load_planner_results
from letspi.learned.trees import Tree, TreeEnsemble
from letspi.method.decide import load_risk_model
from letspi.physics.idm import CAR_IDM, IdmKernel, IdmParams, idm_acceleration
from letspi.physics.neighbours import predict_idm, predict_neighbours
from letspi.physics.social_force import SocialForceScene
from letspi.planners.options import DEFAULT_OPTIONS
from letspi.planners.sf_opt import SocialForceSearchPlanner
from letspi.planners.sf_params import load_sf_params
from letspi.safety.plan_check import check_inputs, check_plans, predicted_inputs
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
    old = check_inputs_mirrored(big, predicted_inputs(big, xy, vxy, repeated(pred, rows)))
    _assert_equal(new, old, "check_plans")
    assert new.collision.any() and not new.collision.all()  # the scenes exercise contacts
    assert np.isfinite(new.min_rear_ttc_s).any() and np.isfinite(new.min_ttc_s).any()
    _assert_equal(check_inputs(big, predicted_inputs(big, xy, vxy, repeated(pred, rows))), old, "check_inputs")


def test_scene_of_scenarios_taken_equals_scene_of_the_taken_batch(scenes: ScenarioBatch) -> None:
    pred = predict_neighbours(scenes, "idm")
    rows = np.repeat(np.arange(len(scenes)), 5)
    a = SocialForceScene.from_batch(scenes, pred).take(rows)
    b = SocialForceScene.from_batch(scenes.take(rows), repeated(pred, rows))
    _assert_equal(a, b, "scene")
    for name, value in vars(a).items():  # NumPy may round exp differently on strided arrays
        assert value.flags.c_contiguous == vars(b)[name].flags.c_contiguous, name


def test_sf_opt_search_matches_the_search_on_the_repeated_batch(scenes: ScenarioBatch) -> None:
    planner = SocialForceSearchPlanner(params=load_sf_params()[0])
    context = planner.context(scenes)
    proposals = planner.propose(scenes, context)
    new = sf_opt_all_candidates(planner, scenes, context, proposals)
    old = sf_opt_on_repeated_batch(planner, scenes, context, proposals)
    for name in ("xy_m", "vxy_mps", "goals_xy_m"):
        assert np.array_equal(getattr(new, name), getattr(old, name)), name
    for key, values in old.info.items():
        assert np.array_equal(new.info[key], values), key
    assert 0 < int(np.sum(new.info["found_safe"])) < len(scenes)  # both branches of the choice are taken


@pytest.mark.parametrize("seed", [4, 13])
def test_sf_check_plans_as_when_it_checked_every_preset(seed: int) -> None:
    """``sf-check`` checks every preset only where its rule needs them (the gate consults and the defaults
    fail a check); plans, choices, reasons and shield columns are those of checking every preset on every
    scenario, including the shield's replacements where the presets were checked and where they were not."""
    scenes = crowded_scenes(40, seed=seed)
    # the shield on the kept defaults too: it then also checks presets where the rule did not
    planner = build_planners(["sf-check"], DEFAULT_OPTIONS.replace(shield_presets=True))[0].planner
    context = planner.context(scenes)
    gated = planner.choose(scenes, context)[1]
    new = planner.plan(scenes)
    old = sf_check_checking_every_preset(planner, scenes, context)
    for name in ("xy_m", "vxy_mps", "goals_xy_m"):
        assert np.array_equal(getattr(new, name), getattr(old, name)), name
    assert set(new.info) == set(old.info)
    for key, values in old.info.items():
        assert np.array_equal(np.asarray(new.info[key]), np.asarray(values)), key
    replaced = np.asarray(new.info["shielded"]) > 0
    assert gated.complete.any() and not gated.complete.all()  # some scenarios need every preset, others not
    assert (replaced & gated.complete).any() and (replaced & ~gated.complete).any()


@pytest.mark.parametrize("seed", [4, 7])
def test_sf_opt_staged_search_matches_the_search_of_every_candidate(seed: int) -> None:
    """The staged search (cheapest candidates first, stop at the first safe one) plans exactly what
    rolling out and checking all 27 candidates of every scenario planned, in both branches: a safe
    candidate found at different stages, and the fallback of scenarios where none is safe."""
    scenes = crowded_scenes(40, seed=seed)
    planner = SocialForceSearchPlanner(params=load_sf_params()[0])
    context = planner.context(scenes)
    proposals = planner.propose(scenes, context)
    new = planner.simulate(scenes, context, proposals)
    old = sf_opt_all_candidates(planner, scenes, context, proposals)
    for name in ("xy_m", "vxy_mps", "goals_xy_m"):
        assert np.array_equal(getattr(new, name), getattr(old, name)), name
    for key in ("k_scale", "lon_factor", "lane_factor", "found_safe"):
        assert np.array_equal(new.info[key], old.info[key]), key
    tried = new.info["n_candidates_tried"]
    n_grid = len(planner.space.grid())
    assert (tried[~new.info["found_safe"]] == n_grid).all()  # no safe candidate: every one was tried
    assert (tried == 1).any() and ((tried > 1) & new.info["found_safe"]).any()  # stops early and late
    assert (~new.info["found_safe"]).any()


def test_idm_prediction_matches_the_per_step_concatenating_loop(scenes: ScenarioBatch) -> None:
    pred = predict_idm(scenes)
    old = predict_idm_concatenating(scenes)
    for name, new_values, old_values in zip(pred._fields, pred, old, strict=True):
        assert np.array_equal(new_values, old_values), name
    vs = pred.vxy_mps[..., 0]
    assert (vs[pred.valid] < np.broadcast_to(vs[..., :1], vs.shape)[pred.valid]).any()  # followers brake


def test_idm_kernel_is_idm_acceleration_as_it_was() -> None:
    rng = np.random.default_rng(0)
    v, v0, v_lead = rng.uniform(0, 40, (3, 50, 7))
    gap = np.where(rng.random((50, 7)) < 0.2, np.inf, rng.uniform(-3, 80, (50, 7)))
    prm = IdmParams.for_classes(rng.integers(1, 3, (50, 7)))
    assert np.array_equal(IdmKernel(v0, prm)(v, gap, v_lead), idm_acceleration_per_call(v, v0, gap, v_lead, prm))
    assert np.array_equal(idm_acceleration(v, v0, gap, v_lead), idm_acceleration_per_call(v, v0, gap, v_lead, CAR_IDM))


@pytest.mark.slow
def test_open_loop_in_worker_processes_stores_the_same_rows(tmp_path: Path, scenes: ScenarioBatch) -> None:
    """``evaluate(..., workers=2)`` scores the batch planners in two spawned processes: same rows."""
    file = tmp_path / "scenes.arrow"
    save_scenarios(scenes, file)
    planners = build_planners(["cv", "sf", "sf-opt"], DEFAULT_OPTIONS)
    evaluate(planners, scenes, tmp_path / "one", EvaluationSettings(scenarios_file=str(file)))
    evaluate(planners, scenes, tmp_path / "two", EvaluationSettings(scenarios_file=str(file), workers=2))
    for p in planners:
        a = load_planner_results(tmp_path / "one", p.name, with_plans=True).sort_values("row").reset_index(drop=True)
        b = load_planner_results(tmp_path / "two", p.name, with_plans=True).sort_values("row").reset_index(drop=True)
        a, b = (f.drop(columns=[c for c in f if c == "inference_s" or c.endswith("cpu_ms")]) for f in (a, b))
        pd.testing.assert_frame_equal(a, b, check_exact=True)
    assert (tmp_path / "two" / "metrics.json").exists() and (tmp_path / "two" / "run.json").exists()


def test_tree_ensemble_walks_all_trees_together_to_the_same_sum() -> None:
    """The risk gate's trees walked together (packed, padded to the largest) sum exactly what walking each
    tree (``Tree.predict``) summed, NaN inputs (the missing-value branch) included."""
    shipped, _ = load_risk_model()
    assert isinstance(shipped, TreeEnsemble)
    stump = Tree(feature=np.array([2, -1, -1]), threshold=np.array([0.5, 0.0, 0.0]),
                 missing_left=np.array([False, False, False]), left=np.array([1, -1, -1]),
                 right=np.array([2, -1, -1]), value=np.array([0.0, -0.25, 0.75]))
    model = replace(shipped, trees=(*shipped.trees[:40], stump, *shipped.trees[40:]))  # trees of two sizes: padded
    rng = np.random.default_rng(0)
    x = rng.normal(size=(300, len(model.feature_names))) * 3.0
    x[rng.random(x.shape) < 0.15] = np.nan
    per_tree = np.full(len(x), model.baseline)
    for tree in model.trees:
        per_tree += tree.predict(x)
    assert np.array_equal(model.raw(x), per_tree)
    assert len(np.unique(per_tree)) > 100  # the rows reach many different leaves
