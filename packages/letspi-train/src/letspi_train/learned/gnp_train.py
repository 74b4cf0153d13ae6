"""End-to-end training of the GNP baseline through the differentiable social force rollout.

Goals (the goal predictor's top goal) and predicted neighbour motion are computed once, as ``GnpPlanner``
does at inference; the recorded neighbour future is never a rollout input. ``GnpNet`` sets tau and the
per-neighbour weights, ``rollout_torch`` plans, and the loss is
``mean_t |p_t - p_t^human|`` [m] + ``collision_weight * mean_t sum_j overlap_x * overlap_y`` [m^2] (box
overlap with the recorded neighbours). AdamW; the best validation epoch is kept; deterministic on CPU.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict
from typing import Any

import numpy as np
import torch

from letspi.constants import T0_INDEX
from letspi.learned.features import scene_features
from letspi.learned.gnp_model import GnpModel, rollout_weighted
from letspi.learned.hyperparams import GnpTrainConfig
from letspi.metrics.collision import boxes_overlap
from letspi.metrics.inputs import MetricInputs
from letspi.metrics.kinematics import ade_fde
from letspi.physics.goals import GoalPredictor
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.params import PARAM_NAMES, SocialForceParams
from letspi.physics.social_force import SocialForceScene
from letspi.scenario.types import ScenarioBatch
from letspi_train.learned.data import split
from letspi_train.learned.loop import TrainResult, data_manifest, fit, merge_manifest, training_manifest
from letspi_train.learned.modules import FeatureTensors, GnpNet, export_state
from letspi_train.learned.torch_sf import TorchScene, rollout_torch


class _Data:
    """Network-independent tensors of a set of scenarios (float32 for speed)."""

    def __init__(self, batch: ScenarioBatch, goals_xy_m: np.ndarray, mode: NeighbourPredictionMode) -> None:
        dt = torch.float32
        self.batch = batch
        self.goals_np = goals_xy_m
        self.nbr = predict_neighbours(batch, mode)
        self.scene_np = SocialForceScene.from_batch(batch, self.nbr)
        self.scene = TorchScene.from_scene(self.scene_np, dt)
        self.feats = FeatureTensors(scene_features(batch), dt)
        self.goals = torch.as_tensor(goals_xy_m, dtype=dt)
        fut = slice(T0_INDEX + 1, None)
        self.truth = torch.as_tensor(np.nan_to_num(batch.ego_xy_m[:, fut].astype(np.float64)), dtype=dt)
        gt_xy = batch.nbr_xy_m[:, :, fut].astype(np.float64)
        ok = batch.nbr_valid[:, :, fut] & np.isfinite(gt_xy).all(axis=-1)
        self.gt_nbr = torch.as_tensor(np.where(ok[..., None], gt_xy, 1e6), dtype=dt)  # (B, N, F, 2)
        self.gt_ok = torch.as_tensor(ok, dtype=dt)
        nl = np.nan_to_num(batch.nbr_length_m.astype(np.float64))
        nw = np.nan_to_num(batch.nbr_width_m.astype(np.float64))
        self.half_len = torch.as_tensor(0.5 * (batch.ego_length_m[:, None] + nl), dtype=dt)  # (B, N)
        self.half_wid = torch.as_tensor(0.5 * (batch.ego_width_m[:, None] + nw), dtype=dt)

    def __len__(self) -> int:
        return len(self.batch)


def _loss(net: GnpNet, d: _Data, idx: torch.Tensor, base: dict[str, float], collision_weight: float) -> torch.Tensor:
    tau, w = net(d.feats.take(idx))
    params = {k: torch.full_like(tau, v) for k, v in base.items()}
    params["tau_s"] = tau
    xy, _ = rollout_torch(d.scene.take(idx), params, d.goals[idx], w)
    err = xy - d.truth[idx]
    ade = torch.sqrt((err * err).sum(dim=-1) + 1e-6).mean(dim=1)
    gx = torch.abs(d.gt_nbr[idx, :, :, 0] - xy[:, None, :, 0])  # (b, N, F)
    gy = torch.abs(d.gt_nbr[idx, :, :, 1] - xy[:, None, :, 1])
    ox = torch.relu(d.half_len[idx][..., None] - gx)
    oy = torch.relu(d.half_wid[idx][..., None] - gy)
    overlap = (ox * oy * d.gt_ok[idx]).sum(dim=1).mean(dim=1)
    return (ade + collision_weight * overlap).mean()


def _plan_metrics(d: _Data, xy: np.ndarray, vxy: np.ndarray) -> dict[str, float]:
    truth = d.batch.ego_xy_m[:, d.batch.future_slice].astype(np.float64)
    ade, fde = ade_fde(xy, truth)
    collided = boxes_overlap(MetricInputs.from_batch(d.batch, xy, vxy)).any(axis=(1, 2))
    return {"ade_m": float(np.nanmean(ade)), "fde_m": float(np.nanmean(fde)),
            "collision_pct": 100.0 * float(collided.mean())}


def train_gnp_model(
    batch: ScenarioBatch,
    cfg: GnpTrainConfig,
    base_params: SocialForceParams,
    goal_predictor: GoalPredictor,
    *,
    progress: Callable[[int], None] | None = None,
    manifest_extra: dict[str, Any] | None = None,
) -> TrainResult:
    """Train on the by-vehicle training split (``progress(1)`` after preparation and each epoch); validation
    metrics for gnp and for plain sf (weights 1) with the same goals and neighbours."""
    mode = NeighbourPredictionMode(cfg.neighbour_mode)
    if mode is NeighbourPredictionMode.GROUND_TRUTH_ORACLE:
        raise ValueError("GNP trains with predicted neighbours, not the recorded future")
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    t_start = time.perf_counter()
    train_idx, val_idx = split(batch, cfg.val_fraction, cfg.seed, cfg.max_train, cfg.max_val)
    tb, vb = batch.take(train_idx), batch.take(val_idx)
    dtr = _Data(tb, goal_predictor.predict_goals(tb).top, mode)
    dva = _Data(vb, goal_predictor.predict_goals(vb).top, mode) if len(vb) else None
    if progress is not None:
        progress(1)
    base = {k: float(getattr(base_params, k)) for k in PARAM_NAMES}

    net = GnpNet(cfg.encoder, float(base_params.tau_s))

    def val_loss() -> float:
        assert dva is not None
        return float(_loss(net, dva, torch.arange(len(dva)), base, cfg.collision_weight))

    history = fit(net, n_train=len(dtr), epochs=cfg.epochs, batch_size=cfg.batch_size, lr=cfg.lr,
                  weight_decay=cfg.weight_decay, seed=cfg.seed,
                  batch_loss=lambda idx: _loss(net, dtr, idx, base, cfg.collision_weight),
                  val_loss=val_loss if dva is not None else None, progress=progress)
    seconds = time.perf_counter() - t_start
    arrays = export_state(net)

    config = {"encoder": cfg.encoder.as_dict(), "base_params": base_params.as_dict(),
              "neighbour_mode": mode.value, "train": {k: v for k, v in asdict(cfg).items() if k != "encoder"}}
    validation: dict[str, Any] = {"n_val": len(val_idx), "best_val_loss": history.best_val}
    if dva is not None:
        model = GnpModel({k: v.astype(np.float64) for k, v in arrays.items()}, cfg.encoder, base_params)
        tau, w = model.predict(scene_features(vb))
        gnp = rollout_weighted(dva.scene_np, model.params_batch(tau), dva.goals_np, w)
        sf = rollout_weighted(dva.scene_np, base_params, dva.goals_np, None)
        validation["gnp"] = {**_plan_metrics(dva, gnp.xy_m, gnp.vxy_mps), "tau_mean_s": float(tau.mean()),
                             "weight_mean": float(w[vb.nbr_valid[:, :, T0_INDEX]].mean())}
        validation["sf"] = _plan_metrics(dva, sf.xy_m, sf.vxy_mps)
    manifest: dict[str, Any] = {
        "model": "gnp", "config": config, "validation": validation,
        "data": data_manifest(len(train_idx), len(val_idx), cfg.val_fraction, cfg.seed),
        "training": training_manifest(seconds, cfg.epochs, history, arrays),
    }
    merge_manifest(manifest, manifest_extra)
    return TrainResult(arrays=arrays, manifest=manifest, train_loss=history.train_loss, val_loss=history.val_loss)
