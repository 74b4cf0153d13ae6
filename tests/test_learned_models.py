"""NumPy inference of the learned models: agreement with torch, weight files, goals, the gnp planner."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from test_learned_scenes import random_batch

from letspi.assembly.build import Builder
from letspi.assembly.planners import BuiltPlanner
from letspi.assembly.resolve import Resolver
from letspi.evaluation.harness import evaluate
from letspi.learned.features import scene_features
from letspi.learned.gnp_model import GnpModel
from letspi.learned.goal_metrics import goal_metrics, goal_truth
from letspi.learned.goal_model import LearnedGoalPredictor
from letspi.learned.layers import EncoderConfig
from letspi.learned.weights import WeightsError, load_weights, save_weights, shipped_weights_dir
from letspi.physics.goals import GoalPrediction, KinematicGoalPredictor
from letspi.physics.lanes import outer_lane_centres_m
from letspi.physics.params import SocialForceParams
from letspi.planners.config import GOAL_WEIGHTS_ENV, GoalsConfig, WeightsConfig
from letspi.planners.gnp import GnpConfig, GnpPlanner
from letspi.planners.options import PlannerOptions
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import concat_batches

SMALL = EncoderConfig(d_model=16, n_heads=2, n_layers=2, d_ff=24)
SHIPPED = (shipped_weights_dir("goal") / "weights.npz").is_file()


def _torch_models(seed: int = 0):  # type: ignore[no-untyped-def]
    torch = pytest.importorskip("torch")
    pytest.importorskip("letspi_train", reason="letspi-train is not installed (pip install -e packages/letspi-train)")
    from letspi_train.learned.modules import GnpNet, GoalNet

    torch.manual_seed(seed)
    goal = GoalNet(SMALL, n_goals=4).double()
    gnp = GnpNet(SMALL, tau_init_s=1.2).double()
    with torch.no_grad():  # non-trivial outputs for the heads that start at zero
        for p in list(gnp.tau_h2.parameters()) + list(gnp.w_h2.parameters()):
            p.normal_(0.0, 0.5)
    return torch, goal, gnp


def test_numpy_goal_inference_equals_torch_forward() -> None:
    torch, goal, _ = _torch_models()
    from letspi_train.learned.modules import FeatureTensors, export_state

    batch = random_batch(np.random.default_rng(5), 16)
    feats = scene_features(batch)
    with torch.no_grad():
        tg, tl = goal(FeatureTensors(feats, torch.float64), 5.0)
    pred = LearnedGoalPredictor(export_state(goal), SMALL, n_goals=4)
    ng, nl = pred.raw_outputs(feats)
    np.testing.assert_allclose(ng, tg.numpy(), rtol=0, atol=1e-9)
    np.testing.assert_allclose(nl, tl.numpy(), rtol=0, atol=1e-9)


def test_numpy_gnp_inference_equals_torch_forward() -> None:
    torch, _, gnp = _torch_models()
    from letspi_train.learned.modules import FeatureTensors, export_state

    batch = random_batch(np.random.default_rng(6), 16)
    feats = scene_features(batch)
    with torch.no_grad():
        tt, tw = gnp(FeatureTensors(feats, torch.float64))
    model = GnpModel(export_state(gnp), SMALL, SocialForceParams())
    nt, nw = model.predict(feats)
    np.testing.assert_allclose(nt, tt.numpy(), rtol=0, atol=1e-9)
    np.testing.assert_allclose(nw, tw.numpy(), rtol=0, atol=1e-9)
    assert ((nt >= 0.3) & (nt <= 3.0)).all()
    assert (nw[~feats.agent_mask[:, 1:]] == 0).all()


def _saved_goal_model(tmp_path: Path) -> Path:
    _, goal, _ = _torch_models(1)
    from letspi_train.learned.modules import export_state

    return save_weights(tmp_path / "goal", export_state(goal),
                        {"model": "goal", "config": {"encoder": SMALL.as_dict(), "n_goals": 4, "horizon_s": 5.0}})


def test_weight_files_round_trip_and_errors(tmp_path: Path) -> None:
    d = _saved_goal_model(tmp_path)
    arrays, manifest = load_weights(d, expected_model="goal")
    assert manifest["model"] == "goal" and manifest["format_version"] == 1
    assert all(a.dtype == np.float64 for a in arrays.values())
    with pytest.raises(WeightsError):
        load_weights(d, expected_model="gnp")
    with pytest.raises(WeightsError):
        load_weights(tmp_path / "missing")
    # an explicitly requested model that does not load is an error, never a silent fallback
    with pytest.raises(WeightsError, match=f"{GOAL_WEIGHTS_ENV}="):
        _ = Resolver(PlannerOptions(), env={GOAL_WEIGHTS_ENV: str(tmp_path / "missing")}).goals


def _shipped_goals() -> LearnedGoalPredictor:
    pred = Builder(cache=None).goal_predictor(Resolver(PlannerOptions(), env={}).goals)
    assert isinstance(pred, LearnedGoalPredictor)
    return pred


def test_goals_are_finite_sorted_and_on_the_road(tmp_path: Path) -> None:
    pred = _shipped_goals() if SHIPPED else LearnedGoalPredictor.from_dir(_saved_goal_model(tmp_path))
    assert isinstance(pred, LearnedGoalPredictor)
    batch = random_batch(np.random.default_rng(8), 40)
    out = pred.predict_goals(batch)
    assert isinstance(out, GoalPrediction)
    assert np.isfinite(out.goals_xy_m).all() and np.isfinite(out.probs).all()
    np.testing.assert_allclose(out.probs.sum(axis=1), 1.0)
    assert (np.diff(out.probs, axis=1) <= 1e-12).all()  # best first
    lo, hi = outer_lane_centres_m(batch.marking_y_m)
    y = out.goals_xy_m[..., 1]
    assert ((y >= lo[:, None] - 1e-9) & (y <= hi[:, None] + 1e-9)).all()
    assert (out.goals_xy_m[..., 0] >= -1e-9).all()


def test_goal_source_falls_back_without_shipped_weights_and_says_so(monkeypatch: pytest.MonkeyPatch,
                                                                     tmp_path: Path) -> None:
    from letspi.assembly import resolve

    monkeypatch.setattr(resolve, "shipped_weights_dir", lambda model: tmp_path / "nothing")
    fallback = Resolver(PlannerOptions(), env={}).goals
    assert fallback.source == "kinematic" and "no usable shipped goal weights" in (fallback.fallback_reason or "")
    assert isinstance(Builder(cache=None).goal_predictor(fallback), KinematicGoalPredictor)
    d = _saved_goal_model(tmp_path)
    chosen = Resolver(PlannerOptions(), env={GOAL_WEIGHTS_ENV: str(d)}).goals
    assert chosen.source == "learned" and chosen.weights_dir == str(d)
    assert isinstance(Builder(cache=None).goal_predictor(chosen), LearnedGoalPredictor)


@pytest.mark.skipif(not SHIPPED, reason="no shipped weights")
def test_shipped_models_load_with_manifests_and_beat_kinematic_goals() -> None:
    pred = _shipped_goals()
    manifest = pred.manifest or {}
    for key in ("config", "data", "validation", "training"):
        assert key in manifest
    assert "letspi train goals" in manifest["training"]["command"]
    val = manifest["validation"]
    assert val["learned"]["min_fde_at_5_m"] <= 0.7 * val["kinematic"]["min_fde_at_1_m"]
    gnp = json.loads((shipped_weights_dir("gnp") / "manifest.json").read_text())
    assert gnp["model"] == "gnp" and gnp["config"]["neighbour_mode"] in ("idm", "constant_velocity")
    size = sum(p.stat().st_size for m in ("goal", "gnp") for p in shipped_weights_dir(m).iterdir())
    assert size < 3_000_000


def test_goal_metrics_definition() -> None:
    g = np.array([[[0.0, 0.0], [10.0, 0.0]], [[0.0, 3.0], [0.0, 0.5]]])
    pred = GoalPrediction(g, np.array([[0.6, 0.4], [0.7, 0.3]]))
    m = goal_metrics(pred, np.array([[10.0, 0.0], [0.0, 0.0]]), ks=(1, 2))
    assert m["min_fde_at_1_m"] == pytest.approx((10.0 + 3.0) / 2)
    assert m["min_fde_at_2_m"] == pytest.approx(0.25)
    assert m["miss_rate_at_1"] == 1.0 and m["miss_rate_at_2"] == 0.0


def _gnp_planner(tmp_path: Path) -> GnpPlanner:
    if (shipped_weights_dir("gnp") / "weights.npz").is_file():
        return GnpPlanner(model=GnpModel.from_dir(shipped_weights_dir("gnp")), goal_predictor=_shipped_goals())
    _, _, gnp = _torch_models(2)
    from letspi_train.learned.modules import export_state

    d = save_weights(tmp_path / "gnp", export_state(gnp), {"model": "gnp", "config": {
        "encoder": SMALL.as_dict(), "base_params": SocialForceParams().as_dict(), "neighbour_mode": "idm"}})
    return GnpPlanner(model=GnpModel.from_dir(d), goal_predictor=KinematicGoalPredictor())


def test_gnp_planner_runs_in_the_evaluation_harness(tmp_path: Path) -> None:
    scenes = [
        straight_road_scenario(ego_speed_mps=32.0, neighbours=[VehicleSpec(x0_m=40.0, speed_mps=22.0)]),
        straight_road_scenario(ego_speed_mps=28.0, neighbours=[VehicleSpec(x0_m=-20.0, speed_mps=30.0),
                                                               VehicleSpec(x0_m=10.0, speed_mps=27.0, lane_offset=1)]),
        straight_road_scenario(ego_speed_mps=25.0),
    ]
    batch = concat_batches([s for s in scenes])
    batch = concat_batches([batch.take([i]) for i in range(3)])
    from dataclasses import replace

    batch = replace(batch, scenario_id=np.array(["a", "b", "c"], dtype=object))
    planner = _gnp_planner(tmp_path)
    config = GnpConfig(goals=GoalsConfig(source="kinematic"), gnp=WeightsConfig(weights_sha256="test", weights_dir="."))
    results = evaluate([BuiltPlanner("gnp", config, planner)], batch, tmp_path / "eval")
    assert "gnp" in results
    assert (tmp_path / "eval" / "metrics.md").read_text().count("gnp") >= 1
    plan = planner.plan(batch)
    assert np.isfinite(plan.xy_m).all() and plan.xy_m.shape == (3, 125, 2)
    assert plan.info["nbr_weight"].shape == (3, batch.n_neighbours)
    # the closing-in case keeps a gap to the slower leader
    gap = 40.0 + 22.0 * np.arange(1, 126) / 25.0 - plan.xy_m[0, :, 0]
    assert gap.min() > 4.5


def test_gnp_refuses_the_ground_truth_neighbour_oracle(tmp_path: Path) -> None:
    planner = _gnp_planner(tmp_path)
    with pytest.raises(ValueError, match="predicted neighbours"):
        GnpPlanner(model=planner.model, goal_predictor=KinematicGoalPredictor(), neighbour_mode="ground_truth_oracle")  # type: ignore[arg-type]


def test_goal_truth_is_the_horizon_position() -> None:
    batch = random_batch(np.random.default_rng(2), 3)
    np.testing.assert_array_equal(goal_truth(batch), batch.ego_xy_m[:, 199].astype(np.float64))
