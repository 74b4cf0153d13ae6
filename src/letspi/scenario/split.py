"""Train/test splits by ego vehicle (recording, ego id) or by recording: a vehicle's windows overlap, so splitting
them would leak evaluation futures into training."""

from __future__ import annotations

import numpy as np

from letspi.scenario.types import ScenarioBatch


def vehicle_keys(batch: ScenarioBatch) -> np.ndarray:
    """(B,) str key of each scenario's ego vehicle: the recording's content key and the ego id."""
    return np.array([f"{r}/{e}" for r, e in zip(batch.recording_key, batch.ego_id, strict=True)], dtype=object)


def split_by_vehicle(batch: ScenarioBatch, train_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices (train, validation): whole ego vehicles (recording, id) go to one side."""
    return split_by_key(vehicle_keys(batch), train_fraction, seed)


def split_by_key(keys: np.ndarray, train_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices (train, validation) of rows with (R,) group ``keys`` (e.g. ``vehicle_keys`` of the rows'
    scenarios): every group goes to one side, ``train_fraction`` of the groups to training."""
    keys = np.asarray(keys).astype(str)
    uniq = np.unique(keys)
    perm = np.random.default_rng(seed).permutation(len(uniq))
    n_train = round(train_fraction * len(uniq))
    train_keys = uniq[perm[:n_train]]
    is_train = np.isin(keys, train_keys)
    return np.flatnonzero(is_train), np.flatnonzero(~is_train)


def split_by_recording(batch: ScenarioBatch, train_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices (train, validation): whole recordings go to one side (needs at least two recordings)."""
    uniq = np.unique(batch.recording_key.astype(str))
    if len(uniq) < 2:
        raise ValueError(f"a split by recording needs at least 2 recordings, the scenarios come from {len(uniq)}")
    perm = np.random.default_rng(seed).permutation(len(uniq))
    n_train = min(max(round(train_fraction * len(uniq)), 1), len(uniq) - 1)
    is_train = np.isin(batch.recording_key.astype(str), uniq[perm[:n_train]])
    return np.flatnonzero(is_train), np.flatnonzero(~is_train)


def subsample(indices: np.ndarray, at_most: int | None, rng: np.random.Generator) -> np.ndarray:
    """``indices`` as they are when there are at most ``at_most`` of them (or ``at_most`` is None), else
    ``at_most`` of them drawn with ``rng`` without replacement, ascending."""
    if at_most is None or len(indices) <= at_most:
        return indices
    return np.sort(rng.choice(indices, at_most, replace=False))
