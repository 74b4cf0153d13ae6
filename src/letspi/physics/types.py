"""Result containers of the physics models: a rollout of F steps starts from t = 0 (frame ``T0_INDEX``) and reports
t = dt ... F dt (the future frames ``T0_INDEX + 1 ...``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from letspi.constants import DT_S


@dataclass(frozen=True)
class RolloutResult:
    """A planned ego trajectory per scenario (ego frame, float64): ``xy_m``, ``vxy_mps`` (B, F, 2) at t = (k + 1) dt;
    ``axy_mps2`` (B, F, 2) the acceleration applied during step k after all clamps, so that
    ``vxy[k] = vxy[k - 1] + dt axy[k]`` exactly."""

    xy_m: np.ndarray
    vxy_mps: np.ndarray
    axy_mps2: np.ndarray
    dt_s: float = DT_S

    def __len__(self) -> int:
        return int(self.xy_m.shape[0])

    @property
    def n_steps(self) -> int:
        return int(self.xy_m.shape[1])


class NeighbourPrediction(NamedTuple):
    """Predicted neighbour trajectories (ego frame, float64): ``xy_m``, ``vxy_mps`` (B, N, F, 2) at t = (k + 1) dt, 0
    where invalid; ``valid`` (B, N, F) bool (the slot is occupied and predictable)."""

    xy_m: np.ndarray
    vxy_mps: np.ndarray
    valid: np.ndarray

    def take(self, rows: np.ndarray | Sequence[int] | slice) -> NeighbourPrediction:
        """The prediction of the selected scenarios (index array, mask or slice)."""
        return NeighbourPrediction(*(np.asarray(a)[rows] for a in self))

    def repeat(self, counts: int | np.ndarray) -> NeighbourPrediction:
        """Each scenario's prediction ``counts`` times in a row (``np.repeat`` on the batch axis)."""
        return NeighbourPrediction(*(np.repeat(np.asarray(a), counts, axis=0) for a in self))

    @staticmethod
    def concat(parts: Sequence[NeighbourPrediction]) -> NeighbourPrediction:
        """The predictions of ``parts`` one after another on the batch axis."""
        return NeighbourPrediction(*(np.concatenate([np.asarray(p[k]) for p in parts]) for k in range(3)))
