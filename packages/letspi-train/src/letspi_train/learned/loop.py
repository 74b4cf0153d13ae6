"""The training loop and manifest pieces shared by letspi's trained models (torch only).

``train_steps`` is the one optimiser loop; ``fit`` runs it for seeded epochs and keeps the best validation
state; ``run_steps`` runs it for a step budget with resumable checkpoints (LoRA fine-tuning).
"""

from __future__ import annotations

import copy
import os
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
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
    """One optimiser step per batch (anything ``batch_loss`` takes): loss, backward, clipping to ``clip_norm``
    (None: none), optimiser and scheduler steps, ``on_step(steps_done, loss)``; returns the losses."""
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
    """One epoch's mini-batches: a permutation of ``range(n)`` from ``generator`` cut into ``batch_size`` pieces."""
    perm = torch.randperm(n, generator=generator)
    return [perm[s : s + batch_size] for s in range(0, len(perm), batch_size)]


class BestState:
    """Keeps the model state with the lowest validation loss (without validation: the last) to restore it."""

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
    """Train ``net`` in place for ``epochs``; ``batch_loss(indices)``: a mini-batch's loss; ``val_loss()`` (None:
    keep the last epoch). ``optimiser``: default AdamW(``lr``, ``weight_decay``). ``progress(1)`` per epoch."""
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


# --------------------------------------------------------------------------------------------------
# A step budget with resumable checkpoints
# --------------------------------------------------------------------------------------------------

CHECKPOINT_FILE = "checkpoint.pt"


class CheckpointMismatchError(ValueError):
    """A checkpoint in the output directory belongs to another run (other data or settings)."""


@dataclass
class StepHistory:
    """Per-step losses and what the run did (``resumed_from``: the step a checkpoint restored, 0 if none)."""

    losses: list[float]
    steps: int
    resumed_from: int
    checkpoints_written: int
    train_s: float


def _atomic_torch_save(obj: Any, path: Path) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as fh:
            torch.save(obj, fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:  # Ctrl-C mid-write: no half-written temporary left behind
        tmp.unlink(missing_ok=True)
        raise


def checkpoint_step(directory: Path) -> int:
    """The optimiser steps the checkpoint in ``directory`` holds (0 without one): where a rerun resumes."""
    ckpt = Path(directory) / CHECKPOINT_FILE
    if not ckpt.is_file():
        return 0
    return int(torch.load(ckpt, map_location="cpu", weights_only=False)["step"])


@dataclass
class _StepRun:
    """The mutable state of ``run_steps`` that a checkpoint holds (besides the trainable weights)."""

    opt: torch.optim.Optimizer
    sched: torch.optim.lr_scheduler.LRScheduler
    rng: np.random.Generator
    fingerprint: dict[str, Any]
    order: list[int]
    losses: list[float]
    start: int = 0
    train_s: float = 0.0
    written: int = 0

    def restore(self, ckpt: Path, load_trainable_state: Callable[[dict[str, torch.Tensor]], None] | None) -> None:
        """Continue from ``ckpt`` (``CheckpointMismatchError`` if it belongs to another run)."""
        state = torch.load(ckpt, map_location="cpu", weights_only=False)
        old = state.get("fingerprint", {})
        if old != self.fingerprint:
            keys = sorted(k for k in set(old) | set(self.fingerprint) if old.get(k) != self.fingerprint.get(k))
            raise CheckpointMismatchError(
                f"{ckpt}: a checkpoint of another run (differs in {', '.join(keys)}); use another --out or "
                "delete the checkpoint to start over")
        if load_trainable_state is None:
            raise ValueError("resuming needs load_trainable_state")
        load_trainable_state(state["trainable"])
        self.opt.load_state_dict(state["optimizer"])
        self.sched.load_state_dict(state["scheduler"])
        self.rng.bit_generator.state = state["rng"]
        torch.set_rng_state(state["torch_rng"])
        self.order, self.losses = list(state["order"]), list(state["losses"])
        self.start, self.train_s = int(state["step"]), float(state["train_s"])

    def save(self, ckpt: Path, step: int, trainable: dict[str, torch.Tensor], train_s: float) -> None:
        ckpt.parent.mkdir(parents=True, exist_ok=True)
        _atomic_torch_save({"fingerprint": self.fingerprint, "step": step, "trainable": trainable,
                            "optimizer": self.opt.state_dict(), "scheduler": self.sched.state_dict(),
                            "rng": self.rng.bit_generator.state, "torch_rng": torch.get_rng_state(),
                            "order": self.order, "losses": self.losses, "train_s": train_s}, ckpt)
        self.written += 1

    def batches(self, total_steps: int, n_train: int, batch_size: int) -> Iterator[list[int]]:
        """The remaining mini-batches: epochs of seeded permutations, consumed ``batch_size`` at a time."""
        for _ in range(self.start, total_steps):
            if len(self.order) < batch_size:
                self.order += [int(i) for i in self.rng.permutation(n_train)]
            idx, self.order = self.order[:batch_size], self.order[batch_size:]
            yield idx


def run_steps(
    model: torch.nn.Module,
    params: list[torch.nn.Parameter],
    *,
    n_train: int,
    total_steps: int,
    batch_size: int,
    lr: float,
    weight_decay: float,
    seed: int,
    batch_loss: Callable[[list[int]], torch.Tensor],
    lr_factor: Callable[[int], float] | None = None,
    clip_norm: float | None = 1.0,
    trainable_state: Callable[[], dict[str, torch.Tensor]] | None = None,
    load_trainable_state: Callable[[dict[str, torch.Tensor]], None] | None = None,
    checkpoint_dir: Path | None = None,
    checkpoint_every_s: float = 300.0,
    fingerprint: dict[str, Any] | None = None,
    progress: Callable[[int, int, float], None] | None = None,
) -> StepHistory:
    """``total_steps`` AdamW steps over ``params`` on seeded, per-epoch reshuffled mini-batches;
    ``lr_factor(step)`` scales the learning rate. Every ``checkpoint_every_s`` and at the end the whole run
    state and ``fingerprint`` (data, settings) go atomically to ``checkpoint_dir / CHECKPOINT_FILE``; a
    checkpoint with the same fingerprint is resumed (same result as an unbroken run), another is refused
    (``CheckpointMismatchError`` naming the differing fields)."""
    opt = torch.optim.AdamW(params, lr=lr, weight_decay=weight_decay)
    run = _StepRun(opt, torch.optim.lr_scheduler.LambdaLR(opt, lr_factor or (lambda _step: 1.0)),
                   np.random.default_rng(seed), fingerprint or {}, [], [])
    ckpt = Path(checkpoint_dir) / CHECKPOINT_FILE if checkpoint_dir is not None else None
    if ckpt is not None and ckpt.is_file():
        run.restore(ckpt, load_trainable_state)
    t0 = time.perf_counter() - run.train_s
    last_save = time.perf_counter()

    def save(step: int) -> None:
        if ckpt is not None and trainable_state is not None:
            run.save(ckpt, step, trainable_state(), time.perf_counter() - t0)

    def on_step(done: int, loss: float) -> None:
        nonlocal last_save
        step = run.start + done
        run.losses.append(loss)
        if progress is not None:
            progress(step, total_steps, loss)
        if time.perf_counter() - last_save >= checkpoint_every_s and step < total_steps:
            save(step)
            last_save = time.perf_counter()

    model.train()
    train_steps(model, opt, run.batches(total_steps, n_train, batch_size), batch_loss, scheduler=run.sched,
                clip_norm=clip_norm, on_step=on_step)
    save(total_steps)
    return StepHistory(run.losses, total_steps, run.start, run.written, time.perf_counter() - t0)
