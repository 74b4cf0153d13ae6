"""Ego goal prediction (where the ego should be at the horizon) and the paper's goal adjustment (§III-E).

``GoalPredictor`` returns K >= 1 candidate goals per scenario, best first: ``KinematicGoalPredictor``
(constant acceleration and a lane-change intention from the history) or ``OracleGoalPredictor`` (the recorded
position: leaks the future). ``adjust_goals`` applies the longitudinal and lane factors.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from letspi.constants import DT_S, HORIZON_S, N_FUTURE, T0_INDEX
from letspi.physics.lanes import (
    DEFAULT_LANE_WIDTH_M,
    lane_centres_m,
    lane_index_of,
    lane_width_m,
    outer_lane_centres_m,
)
from letspi.scenario.types import ScenarioBatch


@dataclass(frozen=True)
class GoalPrediction:
    """goals_xy_m (B, K, 2) in the ego frame [m], best first; probs (B, K), rows sum to 1."""

    goals_xy_m: np.ndarray
    probs: np.ndarray

    def __post_init__(self) -> None:
        g, p = self.goals_xy_m, self.probs
        if g.ndim != 3 or g.shape[2] != 2 or g.shape[1] < 1 or p.shape != g.shape[:2]:
            raise ValueError(f"GoalPrediction expects (B, K>=1, 2) goals and (B, K) probs, got {g.shape}, {p.shape}")

    @property
    def top(self) -> np.ndarray:
        """The best goal per scenario, (B, 2)."""
        return top_goal(self)


def top_goal(prediction: GoalPrediction) -> np.ndarray:
    """The most probable goal per scenario, (B, 2) (index 0 by the best-first convention)."""
    return prediction.goals_xy_m[:, 0, :].copy()


@runtime_checkable
class GoalPredictor(Protocol):
    def predict_goals(self, batch: ScenarioBatch) -> GoalPrediction:
        """Candidate goals at the planning horizon for every scenario in ``batch``."""
        ...


def _single_goal(goals_xy_m: np.ndarray) -> GoalPrediction:
    g = np.asarray(goals_xy_m, dtype=np.float64)
    return GoalPrediction(goals_xy_m=g[:, None, :], probs=np.ones((g.shape[0], 1)))


def _poly_fit_weights(n_frames: int, degree: int, dt_s: float) -> np.ndarray:
    """Least-squares weights W (degree + 1, n): W @ samples at t = -(n - 1) dt ... 0 gives the coefficients of t^i."""
    t = (np.arange(n_frames) - (n_frames - 1)) * dt_s
    design = np.vander(t, degree + 1, increasing=True)
    return np.linalg.pinv(design)


@dataclass(frozen=True)
class KinematicGoalPredictor:
    """Constant-acceleration extrapolation with a lane-change intention (K = 1). A quadratic least-squares fit of x over
    the last ``fit_window_s`` gives speed and acceleration at t = 0 (the latter clipped to ``accel_clip_mps2``; the
    vehicle stops rather than reverses). A linear fit of y gives the lateral speed; the position ``lateral_lookahead_s``
    ahead picks the target lane (at most one lane away), whose centre is the goal's y. Goals stay on the road and never
    behind the ego."""

    fit_window_s: float = 1.0
    horizon_s: float = HORIZON_S
    accel_clip_mps2: tuple[float, float] = (-4.0, 2.0)
    lateral_lookahead_s: float = 3.0

    def predict_goals(self, batch: ScenarioBatch) -> GoalPrediction:
        n_fit = max(3, round(self.fit_window_s / DT_S) + 1)
        hist = batch.ego_xy_m[:, T0_INDEX - n_fit + 1 : T0_INDEX + 1].astype(np.float64)
        x0 = batch.ego_xy0_m[:, 0].astype(np.float64)
        y0 = batch.ego_xy0_m[:, 1].astype(np.float64)
        # fit relative to the t0 sample: only speed and acceleration are used
        rel = hist - hist[:, -1:, :]
        quad = _poly_fit_weights(n_fit, 2, DT_S)
        lin = _poly_fit_weights(n_fit, 1, DT_S)
        speed = np.maximum(np.nan_to_num(rel[:, :, 0] @ quad[1]), 0.0)
        accel = np.clip(np.nan_to_num(2.0 * (rel[:, :, 0] @ quad[2])), *self.accel_clip_mps2)
        vy = np.nan_to_num(rel[:, :, 1] @ lin[1])

        h = self.horizon_s
        # stop instead of reversing when braking
        t_move = np.where(accel < 0.0, np.minimum(h, speed / np.maximum(-accel, 1e-9)), h)
        dx = speed * t_move + 0.5 * accel * t_move**2
        goal_x = x0 + np.maximum(dx, 0.0)

        goal_y = snap_lateral_goal(y0, y0 + vy * self.lateral_lookahead_s, batch.marking_y_m)
        return _single_goal(np.stack([goal_x, goal_y], axis=1))


def snap_lateral_goal(y_now_m: np.ndarray, y_projected_m: np.ndarray, marking_y_m: np.ndarray) -> np.ndarray:
    """Centre of the lane ``y_projected_m`` falls in, at most one lane from the current one, (B,); ``y_now_m`` without
    markings."""
    centres = lane_centres_m(marking_y_m)
    cur = lane_index_of(y_now_m, marking_y_m)
    target = lane_index_of(y_projected_m, marking_y_m)
    target = np.clip(target, cur - 1, cur + 1)
    if centres.shape[1] == 0:
        return np.asarray(y_now_m, dtype=np.float64).copy()
    picked = np.take_along_axis(centres, np.maximum(target, 0)[:, None], axis=1)[:, 0]
    return np.where((target >= 0) & np.isfinite(picked), picked, y_now_m)


@dataclass(frozen=True)
class OracleGoalPredictor:
    """ORACLE: the recorded ego position at the horizon (leaks the future; upper bounds only)."""

    n_steps: int = N_FUTURE

    def predict_goals(self, batch: ScenarioBatch) -> GoalPrediction:
        return _single_goal(batch.ego_xy_m[:, T0_INDEX + self.n_steps].astype(np.float64))


LON_FACTOR_RANGE = (0.0, 1.0)
LANE_FACTOR_RANGE = (-1.0, 1.0)
NEUTRAL_LON_FACTOR = 0.4
"""Longitudinal factor that leaves the goal distance unchanged (1.2 - 0.5 * 0.4 = 1)."""
NEUTRAL_LANE_FACTOR = 0.0


def adjust_goals(
    goals_xy_m: np.ndarray,
    ego_xy0_m: np.ndarray,
    lon_factor: np.ndarray | float,
    lane_factor: np.ndarray | float,
    marking_y_m: np.ndarray,
    *,
    default_lane_width_m: float = DEFAULT_LANE_WIDTH_M,
) -> np.ndarray:
    """Apply the paper's goal adjustment factors; (B, 2) goals in the ego frame [m]. ``lon_factor`` (B,) in [0, 1]
    scales the goal distance ``g_x - x0`` by ``1.2 - 0.5 f``. ``lane_factor`` (B,) in [-1, 1] moves the goal's y towards
    the centre of the lane left (-1) or right (+1) of the goal's lane, proportionally; where that lane does not exist,
    at most to the goal's own lane centre. Results stay between the outermost lane centres. Out-of-range factors are
    clamped; NaN means no adjustment. Without markings, lane shifts use ``default_lane_width_m`` and nothing is
    clamped."""
    g = np.asarray(goals_xy_m, dtype=np.float64).reshape(-1, 2)
    b = g.shape[0]
    x0 = np.asarray(ego_xy0_m, dtype=np.float64).reshape(b, 2)[:, 0]
    f_lon = np.broadcast_to(np.asarray(lon_factor, dtype=np.float64), (b,))
    f_lane = np.broadcast_to(np.asarray(lane_factor, dtype=np.float64), (b,))
    scale = np.where(np.isfinite(f_lon), 1.2 - 0.5 * np.clip(f_lon, *LON_FACTOR_RANGE), 1.0)
    f_lane = np.where(np.isfinite(f_lane), np.clip(f_lane, *LANE_FACTOR_RANGE), 0.0)
    goal_x = x0 + (g[:, 0] - x0) * scale

    my = np.asarray(marking_y_m, dtype=np.float64).reshape(b, -1)
    centres = lane_centres_m(my)
    n_lanes = np.isfinite(centres).sum(axis=1)
    gy = g[:, 1]
    shift_dir = -np.sign(f_lane)  # -1 (left) -> +y
    if centres.shape[1] == 0:
        return np.stack([goal_x, gy + f_lane * -default_lane_width_m], axis=1)
    idx = lane_index_of(gy, my)
    target = np.clip(idx + shift_dir.astype(np.int64), 0, np.maximum(n_lanes - 1, 0))
    target_y = np.take_along_axis(centres, np.maximum(target, 0)[:, None], axis=1)[:, 0]
    lw = lane_width_m(my, default_lane_width_m)
    fallback_y = gy + f_lane * -lw
    has_lanes = n_lanes >= 1
    new_y = np.where(has_lanes, gy + np.abs(f_lane) * (target_y - gy), fallback_y)
    lo, hi = outer_lane_centres_m(my)
    new_y = np.where(has_lanes, np.clip(new_y, lo, hi), new_y)
    return np.stack([goal_x, new_y], axis=1)
