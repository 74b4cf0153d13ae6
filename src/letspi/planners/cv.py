"""``cv``: constant velocity from the t = 0 state (lateral velocity included)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from letspi.constants import DT_S, N_FUTURE
from letspi.keyed import Config
from letspi.planners.base import PlanBatch
from letspi.scenario.types import ScenarioBatch


class CvConfig(Config):
    kind: Literal["cv"] = "cv"


@dataclass
class ConstantVelocityPlanner:
    name: str = "cv"
    batch_size: int = 4096

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        p0 = batch.ego_xy0_m.astype(np.float64)  # (B, 2)
        v0 = batch.ego_vxy0_mps.astype(np.float64)  # (B, 2)
        t_s = np.arange(1, N_FUTURE + 1) * DT_S  # (F,)
        xy = p0[:, None, :] + v0[:, None, :] * t_s[None, :, None]
        vxy = np.broadcast_to(v0[:, None, :], xy.shape).copy()
        return PlanBatch(xy_m=xy, vxy_mps=vxy, goals_xy_m=xy[:, -1].copy())
