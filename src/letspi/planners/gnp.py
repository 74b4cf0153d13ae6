"""``gnp``: the Goal-based Neural Physics baseline (model in ``letspi.learned.gnp_model``), rolled out against
predicted neighbours (GNP's public code moves them along their recorded future: a leak, refused here)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from letspi.keyed import Config
from letspi.learned.features import scene_features
from letspi.learned.gnp_model import GnpModel, rollout_weighted
from letspi.metrics.registry import Metric
from letspi.physics.neighbours import NeighbourPredictionMode
from letspi.physics.params import PARAM_NAMES
from letspi.physics.social_force import SocialForceScene
from letspi.planners.base import PlanBatch, PlanningContext, PredictingPlanner, Proposals
from letspi.planners.config import PREDICTION_OPTIONS, GoalsConfig, WeightsConfig
from letspi.planners.options import PlannerOption, file_option
from letspi.planners.outputs import PARAM_OUTPUTS, output
from letspi.scenario.types import ScenarioBatch

GNP_WEIGHTS_ENV = "LETSPI_GNP_WEIGHTS"
GNP_WEIGHTS = file_option(
    "gnp_weights",
    f"Weights of the gnp planner (from `letspi train gnp`; default: ${GNP_WEIGHTS_ENV}, else the shipped ones)")
OPTIONS: tuple[PlannerOption[Any], ...] = (*PREDICTION_OPTIONS, GNP_WEIGHTS)
OUTPUTS: tuple[Metric, ...] = (
    *PARAM_OUTPUTS,
    output("nbr_weight", "1", "float64", "(B, N) learned weight of each neighbour slot's repulsion"),
)


class GnpConfig(Config):
    kind: Literal["gnp"] = "gnp"
    neighbours: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    goals: GoalsConfig
    gnp: WeightsConfig


@dataclass
class GnpPlanner(PredictingPlanner):
    """Planner ``gnp``; ``info``: the parameters used and ``nbr_weight`` (B, N); ``ValueError`` for the oracle."""

    model: GnpModel
    name: str = "gnp"
    batch_size: int = 1024

    def __post_init__(self) -> None:
        self.neighbour_mode = NeighbourPredictionMode(self.neighbour_mode)
        if self.neighbour_mode is NeighbourPredictionMode.GROUND_TRUTH_ORACLE:
            raise ValueError("gnp must roll out with predicted neighbours (idm or constant_velocity), "
                             "not the recorded future")

    def propose(self, batch: ScenarioBatch, context: PlanningContext) -> Proposals:
        """Learned tau and neighbour weights (``extra["nbr_weight"]`` (B, N)); goals as predicted."""
        tau, weights = self.model.predict(scene_features(batch))
        params = self.model.params_batch(tau)
        b = len(batch)
        info = {name: np.asarray(getattr(params, name), dtype=np.float64) for name in PARAM_NAMES}
        info["nbr_weight"] = weights
        return Proposals(params, np.full(b, np.nan), np.full(b, np.nan), info, extra={"nbr_weight": weights})

    def simulate(self, batch: ScenarioBatch, context: PlanningContext, proposals: Proposals) -> PlanBatch:
        scene = SocialForceScene.from_batch(batch, context.neighbours)
        roll = rollout_weighted(scene, proposals.params, context.goals_xy_m, proposals.extra["nbr_weight"])
        return PlanBatch(xy_m=roll.xy_m, vxy_mps=roll.vxy_mps, goals_xy_m=context.goals_xy_m,
                         info=dict(proposals.info))
