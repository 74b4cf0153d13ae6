"""The social force planner, IDM, neighbour prediction and goal prediction (ego frame, SI units)."""

from letspi.physics.goals import (
    GoalPrediction,
    GoalPredictor,
    KinematicGoalPredictor,
    OracleGoalPredictor,
    adjust_goals,
    top_goal,
)
from letspi.physics.idm import rollout_idm_ego
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.params import (
    DEFAULT_PARAMS,
    PARAM_NAMES,
    PARAM_RANGES,
    SocialForceParams,
)
from letspi.physics.social_force import (
    SocialForceScene,
    rollout_social_force,
    rollout_social_force_scene,
    social_force_terms,
)
from letspi.physics.types import NeighbourPrediction, RolloutResult

__all__ = [
    "DEFAULT_PARAMS",
    "PARAM_NAMES",
    "PARAM_RANGES",
    "GoalPrediction",
    "GoalPredictor",
    "KinematicGoalPredictor",
    "NeighbourPrediction",
    "NeighbourPredictionMode",
    "OracleGoalPredictor",
    "RolloutResult",
    "SocialForceParams",
    "SocialForceScene",
    "adjust_goals",
    "predict_neighbours",
    "rollout_idm_ego",
    "rollout_social_force",
    "rollout_social_force_scene",
    "social_force_terms",
    "top_goal",
]
