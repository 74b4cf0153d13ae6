"""``mlp``: the regressor ablation of the LLM planners (model in ``letspi.learned.param_mlp``).

Per scenario it predicts the eight values an LLM answers (six social-force parameters, two goal
factors) from the matching features, then plans exactly as ``letspi-fast`` does with an LLM's
answer: goal adjustment of the predicted goal and a social force rollout against predicted
neighbours (``letspi.method.reflection.simulate_proposal``). Vectorised over the batch; no LLM.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from letspi.learned.param_mlp import OUTPUT_FIELDS, ParamMlp
from letspi.method.reflection import simulate_proposal
from letspi.physics.goals import GoalPredictor
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.params import SocialForceParams
from letspi.planners.base import PlanBatch
from letspi.planners.config import SocialForcePlannerFields, WeightsConfig
from letspi.scenario.features import scenario_features
from letspi.scenario.types import ScenarioBatch


class MlpConfig(SocialForcePlannerFields):
    """``mlp``: the eight LLM answers regressed from the matching features (``sf_params`` gives r_col_m)."""

    kind: Literal["mlp"] = "mlp"
    mlp: WeightsConfig


@dataclass
class ParamMlpPlanner:
    """Planner ``mlp``: regressed parameters and goal factors, predicted goals and neighbours.

    ``r_col_m``: the fitted ``sf`` decay length (the LLM does not choose it either).
    ``info``: the eight predicted values per scenario.
    """

    model: ParamMlp
    goal_predictor: GoalPredictor
    r_col_m: float
    neighbour_mode: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    name: str = "mlp"
    batch_size: int = 256
    reads_future: bool = False

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        values = self.model.predict(scenario_features(batch))  # (B, 8)
        b = len(batch)
        params = SocialForceParams(**{f: values[:, i].copy() for i, f in enumerate(OUTPUT_FIELDS[:6])},
                                   r_col_m=np.full(b, self.r_col_m))
        goals = self.goal_predictor.predict_goals(batch).top
        sim = simulate_proposal(batch, params, values[:, 6], values[:, 7], goals,
                                predict_neighbours(batch, self.neighbour_mode))
        info = {f: values[:, i].copy() for i, f in enumerate(OUTPUT_FIELDS)}
        return PlanBatch(xy_m=sim.xy_m, vxy_mps=sim.vxy_mps, goals_xy_m=sim.goals_xy_m, info=info)
