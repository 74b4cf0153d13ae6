"""Training of the transformer multi-goal predictor: winner-takes-all over K goals (``wta_loss``).

Only the winning goal regresses, so the K heads specialise into modes (keep lane, change left/right,
faster/slower) and the classifier learns which is likely. AdamW with a one-cycle schedule; the best
validation epoch is kept; deterministic for a seed on CPU.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from letspi.constants import HORIZON_S
from letspi.learned.features import scene_features
from letspi.learned.goal_metrics import goal_metrics, goal_truth
from letspi.learned.goal_model import LearnedGoalPredictor
from letspi.learned.hyperparams import GoalTrainConfig
from letspi.physics.goals import KinematicGoalPredictor
from letspi.scenario.types import ScenarioBatch
from letspi_train.learned.data import split
from letspi_train.learned.loop import TrainResult, data_manifest, fit, merge_manifest, training_manifest
from letspi_train.learned.modules import FeatureTensors, GoalNet, export_state


def wta_loss(goals: torch.Tensor, logits: torch.Tensor, truth: torch.Tensor,
             cls_weight: float, center_weight: float = 0.0) -> torch.Tensor:
    """Mean of ``huber(g_k* - y) + center_weight * huber(g_0 - y) + cls_weight * CE(logits, k*)``, k* the closest
    goal (Huber delta 1 m); goals (B, K, 2) [m], logits (B, K), truth (B, 2) [m]."""
    dist = torch.linalg.vector_norm(goals - truth[:, None, :], dim=-1)
    best = dist.argmin(dim=1)
    win = goals[torch.arange(len(goals)), best]
    reg = F.huber_loss(win, truth, delta=1.0, reduction="none").sum(dim=-1)
    if center_weight > 0.0:
        reg = reg + center_weight * F.huber_loss(goals[:, 0], truth, delta=1.0, reduction="none").sum(dim=-1)
    return (reg + cls_weight * F.cross_entropy(logits, best, reduction="none")).mean()


def train_goal_model(
    batch: ScenarioBatch,
    cfg: GoalTrainConfig,
    *,
    progress: Callable[[int], None] | None = None,
    manifest_extra: dict[str, Any] | None = None,
) -> TrainResult:
    """Train on the by-vehicle training split of ``batch`` (``progress(1)`` after each epoch); validate on the rest."""
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    t_start = time.perf_counter()
    train_idx, val_idx = split(batch, cfg.val_fraction, cfg.seed, cfg.max_train)
    feats = scene_features(batch)
    truth_all = goal_truth(batch)
    ft = FeatureTensors(feats.take(train_idx))
    fv = FeatureTensors(feats.take(val_idx))
    yt = torch.as_tensor(truth_all[train_idx], dtype=torch.float32)
    yv = torch.as_tensor(truth_all[val_idx], dtype=torch.float32)

    net = GoalNet(cfg.encoder, cfg.n_goals)

    def batch_loss(idx: torch.Tensor) -> torch.Tensor:
        goals, logits = net(ft.take(idx), HORIZON_S)
        return wta_loss(goals, logits, yt[idx], cfg.cls_weight, cfg.center_weight)

    def val_loss() -> float:
        vg, vlog = net(fv, HORIZON_S)
        return float(wta_loss(vg, vlog, yv, cfg.cls_weight, cfg.center_weight))

    history = fit(net, n_train=len(train_idx), epochs=cfg.epochs, batch_size=cfg.batch_size, lr=cfg.lr,
                  weight_decay=cfg.weight_decay, seed=cfg.seed, batch_loss=batch_loss,
                  val_loss=val_loss if len(val_idx) else None, one_cycle=True, progress=progress)
    seconds = time.perf_counter() - t_start
    arrays = export_state(net)

    config = {"encoder": cfg.encoder.as_dict(), "n_goals": cfg.n_goals, "horizon_s": HORIZON_S,
              "train": {k: v for k, v in asdict(cfg).items() if k != "encoder"}}
    manifest: dict[str, Any] = {"model": "goal", "config": config}
    validation: dict[str, Any] = {"n_val": len(val_idx), "best_val_loss": history.best_val}
    if len(val_idx):
        vb = batch.take(val_idx)
        learned = LearnedGoalPredictor(weights={k: v.astype(np.float64) for k, v in arrays.items()},
                                       config=cfg.encoder, n_goals=cfg.n_goals).predict_goals(vb)
        validation["learned"] = goal_metrics(learned, truth_all[val_idx])
        validation["kinematic"] = goal_metrics(KinematicGoalPredictor().predict_goals(vb), truth_all[val_idx])
    manifest["validation"] = validation
    manifest["data"] = data_manifest(len(train_idx), len(val_idx), cfg.val_fraction, cfg.seed)
    manifest["training"] = training_manifest(seconds, cfg.epochs, history, arrays)
    merge_manifest(manifest, manifest_extra)
    return TrainResult(arrays=arrays, manifest=manifest, train_loss=history.train_loss, val_loss=history.val_loss)
