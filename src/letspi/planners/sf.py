"""``sf``: the social force model with fixed parameters found by offline optimisation
(``letspi fit sf``), goals from a goal predictor, neighbours by a prediction mode."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from letspi.physics.goals import GoalPredictor, KinematicGoalPredictor
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.params import PARAM_NAMES, SocialForceParams
from letspi.physics.social_force import rollout_social_force
from letspi.planners.base import PlanBatch
from letspi.planners.config import SocialForcePlannerFields
from letspi.scenario.types import ScenarioBatch


class SfConfig(SocialForcePlannerFields):
    kind: Literal["sf"] = "sf"


@dataclass
class SocialForcePlanner:
    params: SocialForceParams
    goal_predictor: GoalPredictor = field(default_factory=KinematicGoalPredictor)
    neighbour_mode: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    name: str = "sf"
    batch_size: int = 4096
    reads_future: bool = False

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        goals = self.goal_predictor.predict_goals(batch).top
        params = self.params.broadcast(len(batch))
        roll = rollout_social_force(batch, params, goals, predict_neighbours(batch, self.neighbour_mode))
        info = {name: np.full(len(batch), getattr(self.params, name)) for name in PARAM_NAMES}
        return PlanBatch(xy_m=roll.xy_m, vxy_mps=roll.vxy_mps, goals_xy_m=goals, info=info)
