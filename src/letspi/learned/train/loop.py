"""The training loop and manifest pieces shared by the goal predictor and GNP (torch only).

``fit`` shuffles with its own seeded generator, steps AdamW (optionally one-cycle), clips gradients,
validates after every epoch and restores the best state, so a seed fixes the result.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

GRAD_CLIP_NORM = 5.0


@dataclass(frozen=True)
class TrainResult:
    """Exported NumPy weights, their manifest and the per-epoch losses."""

    arrays: dict[str, np.ndarray]
    manifest: dict[str, Any]
    train_loss: list[float]
    val_loss: list[float]


@dataclass(frozen=True)
class FitHistory:
    train_loss: list[float]
    val_loss: list[float]
    best_val: float


def fit(
    net: torch.nn.Module,
    *,
    n_train: int,
    epochs: int,
    batch_size: int,
    lr: float,
    weight_decay: float,
    seed: int,
    batch_loss: Callable[[torch.Tensor], torch.Tensor],
    val_loss: Callable[[], float] | None,
    one_cycle: bool = False,
    progress: Callable[[int], None] | None = None,
) -> FitHistory:
    """Train ``net`` in place; ``batch_loss(indices)`` is the loss of a training mini-batch,
    ``val_loss()`` the validation loss (None: no validation, the last epoch is kept).
    ``progress(1)`` after every epoch."""
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=weight_decay)
    sched = None
    if one_cycle:
        steps_per_epoch = max(1, -(-n_train // batch_size))
        sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=epochs * steps_per_epoch,
                                                    pct_start=0.1)
    gen = torch.Generator().manual_seed(seed)
    train_hist: list[float] = []
    val_hist: list[float] = []
    best_state, best_val = copy.deepcopy(net.state_dict()), float("inf")
    for _ in range(epochs):
        net.train()
        perm = torch.randperm(n_train, generator=gen)
        total = 0.0
        for s in range(0, len(perm), batch_size):
            idx = perm[s : s + batch_size]
            loss = batch_loss(idx)
            opt.zero_grad()
            loss.backward()  # type: ignore[no-untyped-call]
            torch.nn.utils.clip_grad_norm_(net.parameters(), GRAD_CLIP_NORM)
            opt.step()
            if sched is not None:
                sched.step()
            total += float(loss.detach()) * len(idx)
        train_hist.append(total / max(n_train, 1))
        vl = float("nan")
        if val_loss is not None:
            net.eval()
            with torch.no_grad():
                vl = val_loss()
        val_hist.append(vl)
        if val_loss is None or vl < best_val:
            best_val, best_state = vl, copy.deepcopy(net.state_dict())
        if progress is not None:
            progress(1)
    net.load_state_dict(best_state)
    return FitHistory(train_hist, val_hist, best_val)


def data_manifest(n_train: int, n_val: int, val_fraction: float, seed: int) -> dict[str, Any]:
    return {"n_train": n_train, "n_val": n_val,
            "split": f"by ego vehicle, {100 * (1 - val_fraction):.0f} % train, seed {seed}"}


def training_manifest(seconds: float, epochs: int, history: FitHistory,
                      arrays: dict[str, np.ndarray]) -> dict[str, Any]:
    return {"seconds": seconds, "epochs": epochs, "train_loss": history.train_loss,
            "val_loss": history.val_loss, "torch": torch.__version__,
            "n_parameters": int(sum(a.size for a in arrays.values()))}


def merge_manifest(manifest: dict[str, Any], extra: dict[str, Any] | None) -> dict[str, Any]:
    """``manifest`` with ``extra`` merged in (dict values one level deep, others replaced)."""
    for key, value in (extra or {}).items():
        if isinstance(value, dict) and isinstance(manifest.get(key), dict):
            manifest[key] = {**manifest[key], **value}
        else:
            manifest[key] = value
    return manifest
