"""The learned multi-goal predictor (NumPy inference of the transformer trained by ``letspi train goals``).

K goals at the horizon from the ego token, as offsets from the kinematic anchor ``a``: ``g_k = a + (10 m * o_kx,
2 m * o_ky)``; sorted best first, kept on the road (y between the outermost lane centres) and never behind the
ego; probabilities are the softmax of the logits."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from letspi.constants import HORIZON_S
from letspi.learned.features import SceneFeatures, scene_features
from letspi.learned.layers import EncoderConfig, encode, linear, relu
from letspi.learned.weights import WeightsError, load_weights
from letspi.physics.goals import GoalPrediction
from letspi.physics.lanes import outer_lane_centres_m
from letspi.scenario.types import ScenarioBatch

GOAL_SCALE_X_M = 10.0
GOAL_SCALE_Y_M = 2.0


def softmax(logits: np.ndarray) -> np.ndarray:
    z = logits - logits.max(axis=-1, keepdims=True)
    e = np.exp(z)
    return e / e.sum(axis=-1, keepdims=True)


@dataclass(frozen=True)
class LearnedGoalPredictor:
    """``GoalPredictor`` backed by trained weights; K goals (B, K, 2) [m] with probabilities (B, K)."""

    weights: dict[str, np.ndarray]
    config: EncoderConfig
    n_goals: int
    horizon_s: float = HORIZON_S
    manifest: dict[str, Any] | None = None

    @classmethod
    def from_dir(cls, path: Path | str) -> LearnedGoalPredictor:
        """Load a model directory written by ``letspi train goals`` (``WeightsError`` if unusable)."""
        arrays, manifest = load_weights(Path(path), expected_model="goal")
        cfg = manifest.get("config", {})
        try:
            enc = EncoderConfig.from_dict(cfg["encoder"])
            n_goals = int(cfg["n_goals"])
            horizon = float(cfg.get("horizon_s", HORIZON_S))
        except (KeyError, TypeError, ValueError) as exc:
            raise WeightsError(f"{path}: manifest config incomplete ({exc})") from exc
        pred = cls(arrays, enc, n_goals, horizon, manifest)
        pred._check_shapes()
        return pred

    def _check_shapes(self) -> None:
        want = self.weights.get("goal_h2.weight")
        if want is None or want.shape[0] != 3 * self.n_goals:
            raise WeightsError("goal weights do not match the manifest (goal_h2.weight)")

    def raw_outputs(self, feats: SceneFeatures) -> tuple[np.ndarray, np.ndarray]:
        """Network outputs before post-processing: goals (B, K, 2) [m] and logits (B, K), network order."""
        tokens = encode(self.weights, self.config, feats)
        out = linear(self.weights, "goal_h2", relu(linear(self.weights, "goal_h1", tokens[:, 0])))
        k = self.n_goals
        off = out[:, : 2 * k].reshape(-1, k, 2)
        gx = feats.anchor_xy[:, 0:1] + GOAL_SCALE_X_M * off[..., 0]
        gy = feats.anchor_xy[:, 1:2] + GOAL_SCALE_Y_M * off[..., 1]
        return np.stack([gx, gy], axis=-1), out[:, 2 * k :]

    def predict_goals(self, batch: ScenarioBatch) -> GoalPrediction:
        if len(batch) == 0:
            return GoalPrediction(np.zeros((0, self.n_goals, 2)), np.zeros((0, self.n_goals)))
        goals, logits = self.raw_outputs(scene_features(batch))
        probs = softmax(logits)
        order = np.argsort(-probs, axis=1, kind="stable")
        goals = np.take_along_axis(goals, order[..., None], axis=1)
        probs = np.take_along_axis(probs, order, axis=1)
        x0 = np.nan_to_num(batch.ego_xy0_m[:, 0].astype(np.float64))
        lo, hi = outer_lane_centres_m(batch.marking_y_m)
        gx = np.maximum(goals[..., 0], x0[:, None])
        gy = goals[..., 1]
        has = np.isfinite(lo) & np.isfinite(hi)
        gy = np.where(has[:, None], np.clip(gy, np.where(has, lo, 0.0)[:, None], np.where(has, hi, 0.0)[:, None]), gy)
        return GoalPrediction(goals_xy_m=np.stack([gx, gy], axis=-1), probs=probs)
