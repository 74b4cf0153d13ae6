"""``sf``: the social force model with fixed fitted parameters (``letspi fit sf``), predicted goals and neighbours."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from letspi.metrics.registry import Metric
from letspi.physics.params import PARAM_NAMES, SocialForceParams
from letspi.physics.social_force import rollout_social_force
from letspi.planners.base import PlanBatch, PlanningContext, PredictingPlanner, Proposals
from letspi.planners.config import SOCIAL_FORCE_OPTIONS, SocialForcePlannerFields
from letspi.planners.options import PlannerOption
from letspi.planners.outputs import PARAM_OUTPUTS
from letspi.scenario.types import ScenarioBatch

OPTIONS: tuple[PlannerOption[Any], ...] = SOCIAL_FORCE_OPTIONS
OUTPUTS: tuple[Metric, ...] = PARAM_OUTPUTS


class SfConfig(SocialForcePlannerFields):
    kind: Literal["sf"] = "sf"


@dataclass
class SocialForcePlanner(PredictingPlanner):
    params: SocialForceParams
    name: str = "sf"
    batch_size: int = 4096

    def propose(self, batch: ScenarioBatch, context: PlanningContext) -> Proposals:
        """The fitted parameters for every scenario; the predicted goal as it is (NaN factors)."""
        b = len(batch)
        info = {name: np.full(b, getattr(self.params, name)) for name in PARAM_NAMES}
        return Proposals(self.params.broadcast(b), np.full(b, np.nan), np.full(b, np.nan), info)

    def simulate(self, batch: ScenarioBatch, context: PlanningContext, proposals: Proposals) -> PlanBatch:
        roll = rollout_social_force(batch, proposals.params, context.goals_xy_m, context.neighbours)
        return PlanBatch(xy_m=roll.xy_m, vxy_mps=roll.vxy_mps, goals_xy_m=context.goals_xy_m,
                         info=dict(proposals.info))
