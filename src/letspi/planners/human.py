"""``human``: ground-truth replay (reads the recorded future, as no planner may), every table's reference row."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from letspi.keyed import Config
from letspi.planners.base import PlanBatch
from letspi.scenario.types import ScenarioBatch


class HumanConfig(Config):
    kind: Literal["human"] = "human"


@dataclass
class HumanPlanner:
    name: str = "human"
    batch_size: int = 4096

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        fut = batch.future_slice
        xy = batch.ego_xy_m[:, fut].astype("float64")
        return PlanBatch(xy_m=xy, vxy_mps=batch.ego_vxy_mps[:, fut].astype("float64"), goals_xy_m=xy[:, -1].copy())
