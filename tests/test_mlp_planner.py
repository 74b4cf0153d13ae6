"""The ``mlp`` regressor ablation: torch training, NumPy inference, planner and configuration key."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from letspi.assembly.build import Builder
from letspi.assembly.planners import build_planner, resolve_planner
from letspi.learned.param_mlp import OUTPUT_FIELDS, OUTPUT_RANGES, ParamMlp
from letspi.learned.weights import WeightsError, save_weights
from letspi.planners.options import PlannerOptions
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.features import scenario_features
from letspi.scenario.split import split_by_key
from letspi.scenario.types import concat_batches

torch = pytest.importorskip("torch")
pytest.importorskip("letspi_train", reason="letspi-train is not installed (pip install -e packages/letspi-train)")
from letspi_train.finetune.mlp_train import MlpTrainConfig, train_mlp  # noqa: E402

K_NP = OUTPUT_FIELDS.index("k_np")


def _data(n: int = 400) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Features (n, 6) whose min_dist decides k_np (close -> strong repulsion); other outputs constant."""
    rng = np.random.default_rng(0)
    feats = np.column_stack([rng.integers(0, 8, n), rng.uniform(20, 35, n), rng.integers(0, 2, n),
                             rng.uniform(5, 60, n), rng.uniform(20, 60, n), rng.uniform(20, 35, n)]).astype(float)
    targets = np.tile([2.0, 20.0, 9.0, 0.2, 0.5, 0.5, 0.4, 0.0], (n, 1))
    targets[:, K_NP] = np.where(feats[:, 3] < 20.0, 45.0, 15.0)
    return feats, targets, np.array([f"d{i}" for i in range(n)], dtype=object)


def test_training_learns_a_mapping_and_numpy_inference_matches(tmp_path: Path) -> None:
    feats, targets, digests = _data()
    res = train_mlp(feats, targets, digests, MlpTrainConfig(epochs=60, seed=0),
                    defaults=np.array([2.0, 20.0, 9.0, 0.2, 0.5, 0.5, 0.4, 0.0]))
    save_weights(tmp_path / "w", res.arrays, res.manifest)
    model = ParamMlp.from_dir(tmp_path / "w")
    pred = model.predict(feats)
    assert pred.shape == (len(feats), 8)
    low = np.array([OUTPUT_RANGES[f][0] for f in OUTPUT_FIELDS])
    high = np.array([OUTPUT_RANGES[f][1] for f in OUTPUT_FIELDS])
    assert ((pred >= low) & (pred <= high)).all()
    val = res.manifest["validation"]
    assert val["rmse"]["k_np"] < 0.5 * val["rmse_sf_defaults"]["k_np"]  # it learnt the rule, unlike the defaults
    close, far = pred[feats[:, 3] < 15, K_NP].mean(), pred[feats[:, 3] > 25, K_NP].mean()
    assert close > 35.0 and far < 25.0
    again = train_mlp(feats, targets, digests, MlpTrainConfig(epochs=60, seed=0))
    np.testing.assert_allclose(again.arrays["net.4.bias"], res.arrays["net.4.bias"])  # same seed, same weights


def test_mlp_planner_plans_and_its_key_pins_the_weights(tmp_path: Path) -> None:
    feats, targets, digests = _data(100)
    for name, epochs in (("a", 5), ("b", 6)):
        res = train_mlp(feats, targets, digests, MlpTrainConfig(epochs=epochs, seed=0))
        save_weights(tmp_path / name, res.arrays, res.manifest)
    opts = PlannerOptions(goals="kinematic", mlp_weights=tmp_path / "a")
    config = resolve_planner("mlp", opts)
    assert config.key() != resolve_planner("mlp", opts.replace(mlp_weights=tmp_path / "b")).key()
    batch = concat_batches([
        straight_road_scenario(ego_speed_mps=33.0, neighbours=[VehicleSpec(x0_m=40.0, speed_mps=20.0)],
                               scenario_id="a"),
        straight_road_scenario(ego_speed_mps=28.0, scenario_id="b"),
    ])
    planner = build_planner(config, builder=Builder(cache=None)).planner
    plan = planner.plan(batch.history())
    assert plan.xy_m.shape == (2, 125, 2) and np.isfinite(plan.xy_m).all()
    expected = ParamMlp.from_dir(tmp_path / "a").predict(scenario_features(batch.history()))
    np.testing.assert_allclose(plan.info["k_np"], expected[:, K_NP])
    with pytest.raises(ValueError, match="mlp-weights"):
        resolve_planner("mlp", PlannerOptions(goals="kinematic"), env={})
    with pytest.raises(WeightsError, match="nowhere"):
        resolve_planner("mlp", opts.replace(mlp_weights=tmp_path / "nowhere"))


def test_the_split_keeps_each_vehicle_on_one_side() -> None:
    """Overlapping windows of one vehicle (same key) never straddle train and validation."""
    keys = np.repeat([f"rec/{i}" for i in range(50)], 4)  # 4 windows per vehicle
    train, val = split_by_key(keys, 0.8, seed=3)
    assert len(train) + len(val) == len(keys) and len(val) == 40  # 10 of 50 vehicles
    assert set(keys[train]).isdisjoint(set(keys[val]))
    feats, targets, _ = _data(200)
    res = train_mlp(feats, targets, keys, MlpTrainConfig(epochs=3, seed=3))
    assert res.manifest["data"]["n_val_vehicles"] == 10 and res.manifest["data"]["n_train_vehicles"] == 40
