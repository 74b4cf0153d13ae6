"""The training loop and manifest pieces shared by the goal predictor and GNP (torch only).

``fit`` shuffles with its own seeded generator, steps AdamW (optionally one-cycle), clips gradients,
validates after every epoch and restores the best state, so a seed fixes the result.
"""

from __future__ import annotations

import copy
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
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


# --------------------------------------------------------------------------------------------------
# Step-based training with checkpoints (the LoRA fine-tuning; long runs that must survive a kill)
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
    with open(tmp, "wb") as fh:
        torch.save(obj, fh)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def run_steps(
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
    grad_clip: float = 1.0,
    trainable_state: Callable[[], dict[str, torch.Tensor]] | None = None,
    load_trainable_state: Callable[[dict[str, torch.Tensor]], None] | None = None,
    checkpoint_dir: Path | None = None,
    checkpoint_every_s: float = 300.0,
    fingerprint: dict[str, Any] | None = None,
    progress: Callable[[int, int, float], None] | None = None,
) -> StepHistory:
    """``total_steps`` AdamW steps over mini-batches of ``batch_size`` training indices (reshuffled,
    seeded, every epoch); ``batch_loss(indices)`` returns the mini-batch loss; ``lr_factor(step)`` scales
    the learning rate (LambdaLR).

    Checkpoints (``checkpoint_dir``): every ``checkpoint_every_s`` seconds of training and at the end,
    the trainable state, optimiser, schedule, batch order, losses and ``fingerprint`` (what identifies
    the run: data, settings) are written atomically to ``CHECKPOINT_FILE``. A run that finds a
    checkpoint with the same fingerprint continues from it (same batches, same result as an unbroken
    run); another fingerprint is refused (``CheckpointMismatchError`` naming the differing fields).
    """
    opt = torch.optim.AdamW(params, lr=lr, weight_decay=weight_decay)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lr_factor or (lambda _step: 1.0))
    rng = np.random.default_rng(seed)
    order: list[int] = []
    losses: list[float] = []
    start, train_s, written = 0, 0.0, 0
    fingerprint = fingerprint or {}
    ckpt = Path(checkpoint_dir) / CHECKPOINT_FILE if checkpoint_dir is not None else None
    if ckpt is not None and ckpt.is_file():
        state = torch.load(ckpt, map_location="cpu", weights_only=False)
        old = state.get("fingerprint", {})
        if old != fingerprint:
            keys = sorted(k for k in set(old) | set(fingerprint) if old.get(k) != fingerprint.get(k))
            raise CheckpointMismatchError(
                f"{ckpt}: a checkpoint of another run (differs in {', '.join(keys)}); use another --out or "
                "delete the checkpoint to start over")
        if load_trainable_state is None:
            raise ValueError("resuming needs load_trainable_state")
        load_trainable_state(state["trainable"])
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
        rng.bit_generator.state = state["rng"]
        torch.set_rng_state(state["torch_rng"])
        order, losses = list(state["order"]), list(state["losses"])
        start, train_s = int(state["step"]), float(state["train_s"])

    def save(step: int, elapsed: float) -> None:
        nonlocal written
        if ckpt is None or trainable_state is None:
            return
        ckpt.parent.mkdir(parents=True, exist_ok=True)
        _atomic_torch_save({"fingerprint": fingerprint, "step": step, "trainable": trainable_state(),
                            "optimizer": opt.state_dict(), "scheduler": sched.state_dict(),
                            "rng": rng.bit_generator.state, "torch_rng": torch.get_rng_state(),
                            "order": order, "losses": losses, "train_s": elapsed}, ckpt)
        written += 1

    t0 = time.perf_counter() - train_s
    last_save = time.perf_counter()
    for step in range(start, total_steps):
        if len(order) < batch_size:
            order += [int(i) for i in rng.permutation(n_train)]
        idx, order = order[:batch_size], order[batch_size:]
        loss = batch_loss(idx)
        opt.zero_grad(set_to_none=True)
        loss.backward()  # type: ignore[no-untyped-call]
        torch.nn.utils.clip_grad_norm_(params, grad_clip)
        opt.step()
        sched.step()
        losses.append(float(loss.detach()))
        if progress is not None:
            progress(step + 1, total_steps, losses[-1])
        if time.perf_counter() - last_save >= checkpoint_every_s and step + 1 < total_steps:
            save(step + 1, time.perf_counter() - t0)
            last_save = time.perf_counter()
    train_s = time.perf_counter() - t0
    save(total_steps, train_s)
    return StepHistory(losses, total_steps, start, written, train_s)
