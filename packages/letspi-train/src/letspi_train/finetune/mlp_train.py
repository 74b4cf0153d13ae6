"""Training of the ``mlp`` regressor (``letspi.learned.param_mlp``) on the safe ``propose`` labels (torch).

Inputs: the matching features of each row's scenario (the file's digest must match the manifest); split
80 / 20 by ego vehicle; loss: MSE of outputs normalised by the field ranges (``letspi_train.learned.loop.fit``).
Validation reports the per-field RMSE beside that of always answering the fitted defaults, so a regressor
that learnt nothing shows.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from letspi.learned.param_mlp import MODEL_NAME, OUTPUT_FIELDS, OUTPUT_RANGES
from letspi.scenario.features import FEATURE_NAMES, scenario_features
from letspi.scenario.identity import dataset_digest, scenario_digests
from letspi.scenario.split import split_by_key, vehicle_keys
from letspi.scenario.store import load_scenarios
from letspi_train.finetune.labels import load_labels
from letspi_train.learned.loop import fit


@dataclass(frozen=True)
class MlpTrainConfig:
    hidden: int = 64
    epochs: int = 300
    lr: float = 3e-3
    weight_decay: float = 1e-4
    batch_size: int = 256
    val_share: float = 0.2
    seed: int = 0
    threads: int = 1


@dataclass(frozen=True)
class MlpResult:
    arrays: dict[str, np.ndarray]
    manifest: dict[str, Any]


def load_training_rows(label_dirs: list[Path]) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
    """Features (R, 6), targets (R, 8), ego-vehicle keys (R,) and per-directory provenance."""
    feats, targets, vehicles, infos = [], [], [], []
    for d in label_dirs:
        df, manifest = load_labels(d)
        rows = df[(df["kind"] == "propose") & df["label_safe"]]
        path = Path(manifest["scenarios_path"])
        batch = load_scenarios(path)
        n = int(manifest.get("n_scenarios_total", len(batch)))
        batch = batch.take(slice(0, n))
        digest = dataset_digest(scenario_digests(batch))
        if digest != manifest["dataset_digest"]:
            raise ValueError(f"{d}: the labels were made from other scenarios than {path} holds now "
                             f"(dataset digest {manifest['dataset_digest']} != {digest})")
        idx = rows["scenario_index"].to_numpy(dtype=np.int64)
        feats.append(scenario_features(batch.take(idx).history()))
        targets.append(rows[list(OUTPUT_FIELDS)].to_numpy(dtype=np.float64))
        vehicles.append(vehicle_keys(batch.take(idx)))
        infos.append({"dir": str(d), "labels_sha256": manifest.get("labels_sha256"),
                      "dataset_digest": manifest["dataset_digest"], "n_rows": len(rows),
                      "sf_params": manifest.get("sf_params")})
    return np.concatenate(feats), np.concatenate(targets), np.concatenate(vehicles), infos


def train_mlp(features: np.ndarray, targets: np.ndarray, vehicles: np.ndarray, cfg: MlpTrainConfig,
              defaults: np.ndarray | None = None) -> MlpResult:
    """Fit the regressor; returns weight arrays (names as ``ParamMlp`` expects) and a manifest."""
    t0 = time.perf_counter()
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    low = np.array([OUTPUT_RANGES[f][0] for f in OUTPUT_FIELDS])
    high = np.array([OUTPUT_RANGES[f][1] for f in OUTPUT_FIELDS])
    x = np.nan_to_num(features.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    y = (np.clip(targets, low, high) - low) / (high - low)
    val = np.zeros(len(features), dtype=bool)
    val[split_by_key(vehicles, 1.0 - cfg.val_share, cfg.seed)[1]] = True
    mean = x[~val].mean(axis=0)
    std = np.maximum(x[~val].std(axis=0), 1e-6)
    z = (x - mean) / std
    net = nn.Sequential(nn.Linear(x.shape[1], cfg.hidden), nn.ReLU(), nn.Linear(cfg.hidden, cfg.hidden), nn.ReLU(),
                        nn.Linear(cfg.hidden, len(OUTPUT_FIELDS)))
    xt = torch.tensor(z[~val], dtype=torch.float32)
    yt = torch.tensor(y[~val], dtype=torch.float32)
    xv = torch.tensor(z[val], dtype=torch.float32)
    yv = torch.tensor(y[val], dtype=torch.float32)

    def batch_loss(idx: torch.Tensor) -> torch.Tensor:
        return ((torch.sigmoid(net(xt[idx])) - yt[idx]) ** 2).mean()

    def val_loss() -> float:
        return float(((torch.sigmoid(net(xv)) - yv) ** 2).mean()) if len(xv) else float("nan")

    history = fit(net, n_train=len(xt), epochs=cfg.epochs, batch_size=cfg.batch_size, lr=cfg.lr,
                  weight_decay=cfg.weight_decay, seed=cfg.seed, batch_loss=batch_loss,
                  val_loss=val_loss if len(xv) else None)
    arrays = {k: v.detach().numpy().astype(np.float64) for k, v in net.state_dict().items()}
    arrays = {f"net.{k}": v for k, v in arrays.items()}
    arrays.update(feat_mean=mean, feat_std=std, low=low, high=high)

    with torch.no_grad():
        pred = torch.sigmoid(net(torch.tensor(z, dtype=torch.float32))).numpy().astype(np.float64)
    pred_values = low + (high - low) * pred

    def rmse(a: np.ndarray, b: np.ndarray) -> dict[str, float]:
        return {f: float(np.sqrt(np.mean((a[:, i] - b[:, i]) ** 2))) for i, f in enumerate(OUTPUT_FIELDS)}

    truth = low + (high - low) * y
    validation: dict[str, Any] = {"n": int(val.sum()), "rmse": rmse(pred_values[val], truth[val])}
    if defaults is not None:
        validation["rmse_sf_defaults"] = rmse(np.broadcast_to(defaults, truth[val].shape), truth[val])
    manifest = {
        "model": MODEL_NAME,
        "config": {"hidden": cfg.hidden, "features": list(FEATURE_NAMES), "outputs": list(OUTPUT_FIELDS)},
        "data": {"n_train": int((~val).sum()), "n_val": int(val.sum()),
                 "split": f"by ego vehicle, {100 * (1 - cfg.val_share):.0f} % train, seed {cfg.seed}",
                 "n_train_vehicles": len(np.unique(vehicles[~val].astype(str))),
                 "n_val_vehicles": len(np.unique(vehicles[val].astype(str)))},
        "validation": validation,
        "training": {"epochs": cfg.epochs, "best_val_loss": history.best_val,
                     "lr": cfg.lr, "weight_decay": cfg.weight_decay, "seed": cfg.seed,
                     "batch_size": cfg.batch_size, "seconds": time.perf_counter() - t0,
                     "torch": torch.__version__},
    }
    return MlpResult(arrays, manifest)
