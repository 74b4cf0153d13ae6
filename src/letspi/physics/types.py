"""Result containers shared by the physics models (data only).

Time convention: a rollout of F steps starts from the state at t = 0 (frame ``T0_INDEX``) and
reports the states at t = dt, 2 dt, ..., F dt, i.e. the future frames ``T0_INDEX + 1 ...``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from letspi.constants import DT_S


@dataclass(frozen=True)
class RolloutResult:
    """A planned ego trajectory per scenario (ego frame, float64).

    xy_m (B, F, 2): positions at t = (k + 1) dt, k = 0..F-1.
    vxy_mps (B, F, 2): velocities at the same instants.
    axy_mps2 (B, F, 2): the acceleration applied during step k (from t = k dt to (k + 1) dt), after
        all clamps, so that ``vxy[k] = vxy[k - 1] + dt * axy[k]`` holds exactly.
    dt_s: the step length.
    """

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
    """Predicted neighbour trajectories over the future frames (ego frame, float64).

    xy_m (B, N, F, 2) and vxy_mps (B, N, F, 2) at t = (k + 1) dt; 0 where invalid.
    valid (B, N, F) bool: the prediction exists (the neighbour slot is occupied and predictable).
    """

    xy_m: np.ndarray
    vxy_mps: np.ndarray
    valid: np.ndarray
