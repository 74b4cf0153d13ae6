"""Learned components: the transformer multi-goal predictor and the GNP baseline.

Inference is NumPy only (``goal_model``, ``gnp_model``, ``layers``, ``features``, ``weights``);
training lives in ``letspi.learned.train`` and needs torch (``pip install 'letspi[train]'``).

Public API:

* ``LearnedGoalPredictor.from_dir(path)``; ``GnpModel.from_dir(path)`` (which directory, shipped or
  ``$LETSPI_GOAL_WEIGHTS`` / ``$LETSPI_GNP_WEIGHTS``, is decided by ``letspi.assembly.resolve``).
* ``goal_metrics`` (minFDE@K, miss rate), ``scene_features``, ``save_weights`` / ``load_weights``.
"""

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
