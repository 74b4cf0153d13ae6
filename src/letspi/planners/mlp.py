"""``mlp``: the regressor ablation of the LLM planners: the eight values an LLM answers, predicted from the
matching features (``letspi.learned.param_mlp``), planned as ``letspi-fast`` plans an answer."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from letspi.learned.param_mlp import OUTPUT_FIELDS, ParamMlp
from letspi.method.reflection import simulate_proposal
from letspi.metrics.registry import Metric
from letspi.physics.params import SocialForceParams
from letspi.planners.base import PlanBatch, PlanningContext, PredictingPlanner, Proposals
from letspi.planners.config import SOCIAL_FORCE_OPTIONS, SocialForcePlannerFields, WeightsConfig
from letspi.planners.options import PlannerOption, file_option
from letspi.planners.outputs import LANE_FACTOR, LON_FACTOR, PARAM_OUTPUTS
from letspi.scenario.features import scenario_features
from letspi.scenario.types import ScenarioBatch

MLP_WEIGHTS_ENV = "LETSPI_MLP_WEIGHTS"
MLP_WEIGHTS = file_option(
    "mlp_weights",
    f"Weights of the mlp regressor (from `letspi train mlp`; default: ${MLP_WEIGHTS_ENV}; nothing is shipped)")
OPTIONS: tuple[PlannerOption[Any], ...] = (*SOCIAL_FORCE_OPTIONS, MLP_WEIGHTS)
OUTPUTS: tuple[Metric, ...] = (*PARAM_OUTPUTS, LON_FACTOR, LANE_FACTOR)


class MlpConfig(SocialForcePlannerFields):
    kind: Literal["mlp"] = "mlp"
    mlp: WeightsConfig


@dataclass
class ParamMlpPlanner(PredictingPlanner):
    """Planner ``mlp``; ``r_col_m``: the fitted ``sf`` value (the LLM does not choose it either); ``info``: the
    eight predicted values."""

    model: ParamMlp
    r_col_m: float
    name: str = "mlp"
    batch_size: int = 256

    def propose(self, batch: ScenarioBatch, context: PlanningContext) -> Proposals:
        values = self.model.predict(scenario_features(batch))  # (B, 8)
        b = len(batch)
        params = SocialForceParams(**{f: values[:, i].copy() for i, f in enumerate(OUTPUT_FIELDS[:6])},
                                   r_col_m=np.full(b, self.r_col_m))
        info = {f: values[:, i].copy() for i, f in enumerate(OUTPUT_FIELDS)}
        return Proposals(params, values[:, 6].copy(), values[:, 7].copy(), info)

    def simulate(self, batch: ScenarioBatch, context: PlanningContext, proposals: Proposals) -> PlanBatch:
        sim = simulate_proposal(batch, proposals.params, proposals.lon_factor, proposals.lane_factor,
                                context.goals_xy_m, context.neighbours)
        return PlanBatch(xy_m=sim.xy_m, vxy_mps=sim.vxy_mps, goals_xy_m=sim.goals_xy_m, info=dict(proposals.info))
