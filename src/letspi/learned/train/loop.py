"""The training loop and manifest pieces shared by letspi's trained models (torch only).

``train_steps`` is the optimiser loop (loss, backward, clipping, optimiser and scheduler steps, a
callback per step) over any batches; ``fit`` runs it for epochs of ``shuffled_batches`` from its own
seeded generator, steps AdamW (optionally one-cycle), validates after every epoch and restores the
best state (``BestState``), so a seed fixes the result.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, TypeVar

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


B = TypeVar("B")


def train_steps(
    model: torch.nn.Module,
    optimiser: torch.optim.Optimizer,
    batches: Iterable[B],
    batch_loss: Callable[[B], torch.Tensor],
    *,
    scheduler: torch.optim.lr_scheduler.LRScheduler | None = None,
    clip_norm: float | None = GRAD_CLIP_NORM,
    on_step: Callable[[int, float], None] | None = None,
) -> list[float]:
    """One optimiser step per batch: loss, backward, gradient clipping (``clip_norm``; None: none),
    ``optimiser`` and ``scheduler`` steps. ``on_step(steps_done, loss)`` after each; returns the losses.

    The one optimiser loop of letspi's training code: epochs (``fit``) and step budgets call it with
    their own batches (any objects ``batch_loss`` understands: index tensors, collated examples)."""
    losses: list[float] = []
    for batch in batches:
        loss = batch_loss(batch)
        optimiser.zero_grad()
        loss.backward()  # type: ignore[no-untyped-call]
        if clip_norm is not None:
            torch.nn.utils.clip_grad_norm_(model.parameters(), clip_norm)
        optimiser.step()
        if scheduler is not None:
            scheduler.step()
        losses.append(float(loss.detach()))
        if on_step is not None:
            on_step(len(losses), losses[-1])
    return losses


def shuffled_batches(n: int, batch_size: int, generator: torch.Generator) -> list[torch.Tensor]:
    """One epoch's mini-batches of row indices: a permutation of ``range(n)`` drawn from ``generator``,
    cut into ``batch_size`` pieces (the last may be shorter)."""
    perm = torch.randperm(n, generator=generator)
    return [perm[s : s + batch_size] for s in range(0, len(perm), batch_size)]


class BestState:
    """Checkpoint hook: keeps a copy of the model's state with the lowest validation loss so far
    (every state when there is no validation: the last one wins) and restores it at the end."""

    def __init__(self, model: torch.nn.Module) -> None:
        self.state, self.val_loss = copy.deepcopy(model.state_dict()), float("inf")

    def offer(self, model: torch.nn.Module, val_loss: float | None) -> None:
        if val_loss is None or val_loss < self.val_loss:
            self.val_loss = float("nan") if val_loss is None else val_loss
            self.state = copy.deepcopy(model.state_dict())

    def restore(self, model: torch.nn.Module) -> None:
        model.load_state_dict(self.state)


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
    optimiser: torch.optim.Optimizer | None = None,
    clip_norm: float | None = GRAD_CLIP_NORM,
) -> FitHistory:
    """Train ``net`` in place for ``epochs`` epochs; ``batch_loss(indices)`` is the loss of a training
    mini-batch, ``val_loss()`` the validation loss (None: no validation, the last epoch is kept).
    ``optimiser``: default AdamW(``lr``, ``weight_decay``) over all parameters. ``progress(1)`` after
    every epoch."""
    opt = optimiser or torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=weight_decay)
    sched = None
    if one_cycle:
        steps_per_epoch = max(1, -(-n_train // batch_size))
        sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=epochs * steps_per_epoch,
                                                    pct_start=0.1)
    gen = torch.Generator().manual_seed(seed)
    train_hist: list[float] = []
    val_hist: list[float] = []
    best = BestState(net)
    for _ in range(epochs):
        net.train()
        batches = shuffled_batches(n_train, batch_size, gen)
        losses = train_steps(net, opt, batches, batch_loss, scheduler=sched, clip_norm=clip_norm)
        train_hist.append(sum(loss * len(idx) for loss, idx in zip(losses, batches, strict=True)) / max(n_train, 1))
        vl = None
        if val_loss is not None:
            net.eval()
            with torch.no_grad():
                vl = val_loss()
        val_hist.append(float("nan") if vl is None else vl)
        best.offer(net, vl)
        if progress is not None:
            progress(1)
    best.restore(net)
    return FitHistory(train_hist, val_hist, best.val_loss)


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
