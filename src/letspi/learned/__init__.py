"""Learned components with NumPy inference: the multi-goal predictor, GNP and the risk gate's models (trained by the
companion distribution letspi-train, ``letspi_train.learned``)."""

from letspi.learned.features import SceneFeatures, scene_features
from letspi.learned.gnp_model import GnpModel, rollout_weighted
from letspi.learned.goal_metrics import goal_metrics, goal_truth
from letspi.learned.goal_model import LearnedGoalPredictor
from letspi.learned.weights import WeightsError, load_weights, save_weights, shipped_weights_dir

__all__ = [
    "GnpModel",
    "LearnedGoalPredictor",
    "SceneFeatures",
    "WeightsError",
    "goal_metrics",
    "goal_truth",
    "load_weights",
    "rollout_weighted",
    "save_weights",
    "scene_features",
    "shipped_weights_dir",
]
