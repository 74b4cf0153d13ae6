"""Training data: scenario files -> one batch, and the by-vehicle train/validation split."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from letspi.scenario.split import split_by_vehicle, subsample
from letspi.scenario.store import load_scenarios, read_scenario_meta
from letspi.scenario.types import ScenarioBatch, concat_batches


def load_training_scenarios(paths: Sequence[Path]) -> tuple[ScenarioBatch, list[dict[str, Any]]]:
    """All scenarios of ``paths`` in one batch (files' vehicles stay apart) and each file's provenance record."""
    if not paths:
        raise ValueError("no scenario file given")
    batches, infos = [], []
    for p in paths:
        b = load_scenarios(Path(p))
        batches.append(b)
        meta = read_scenario_meta(Path(p))
        infos.append({"file": str(p), "n_scenarios": len(b), "provenance": meta.get("provenance")})
    return concat_batches(batches), infos


def split(batch: ScenarioBatch, val_fraction: float, seed: int, max_train: int | None = None,
          max_val: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(train, validation) indices split by ego vehicle, optionally subsampled (deterministic for ``seed``)."""
    train, val = split_by_vehicle(batch, 1.0 - val_fraction, seed)
    rng = np.random.default_rng(seed + 1)
    train = subsample(train, max_train, rng)  # first: the validation draw continues the same generator
    return train, subsample(val, max_val, rng)
