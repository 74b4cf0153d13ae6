"""Scene -> fixed-size inputs of the learned models, from frames t <= 0 only, in the ego frame at t = 0; fixed
scales (not data statistics) keep every input of order 1 on any data set."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from letspi.arrays import Rows
from letspi.constants import HORIZON_S, T0_INDEX
from letspi.physics.goals import KinematicGoalPredictor
from letspi.physics.lanes import lane_centres_m, lane_index_of, lane_width_m
from letspi.scenario.types import VEHICLE_CLASS_TRUCK, ScenarioBatch

HIST_STRIDE: Final = 5
N_HIST_STEPS: Final = 15
HIST_FRAMES: Final = tuple(T0_INDEX - HIST_STRIDE * (N_HIST_STEPS - 1 - i) for i in range(N_HIST_STEPS))
MAX_MARKINGS: Final = 8
N_STEP_FEATURES: Final = 5
N_STATIC_FEATURES: Final = 6
N_LANE_FEATURES: Final = 2 * MAX_MARKINGS + 6

SCALE_X_M: Final = 50.0
SCALE_Y_M: Final = 5.0
SCALE_VX_MPS: Final = 30.0
SCALE_VY_MPS: Final = 2.0


@dataclass(frozen=True)
class SceneFeatures(Rows):
    """Model inputs (float64) for B scenarios, A = 1 + N agents (slot 0 the ego), H = ``N_HIST_STEPS``.

    * ``agent_hist`` (B, A, H, 5): every 0.2 s up to t = 0: x / 50 m, y / 5 m, vx / 30 m/s, vy / 2 m/s, valid;
      invalid samples all 0.
    * ``agent_static`` (B, A, 6): length / 5 m, width / 2 m, is_truck, is_ego, offset from the lane centre
      / 2 m, lane index relative to the ego's (+1 = left); 0 when unknown.
    * ``agent_mask`` (B, A) bool: the ego, and neighbours visible at t = 0 (no others can act on the plan).
    * ``lane`` (B, 2 * MAX_MARKINGS + 6): per marking (ascending y) (y - ego y) / 5 m, then its kind (+1 edge,
      -1 line, 0 padding); lane width / 4 m, lanes left and right of the ego / 3, speed limit / 40 m/s, the
      anchor's (x - vx0 * 5 s) / 10 m and y / 5 m.
    * ``anchor_xy`` (B, 2) [m]: the ``KinematicGoalPredictor`` goal; the goal network predicts offsets from it."""

    agent_hist: np.ndarray
    agent_static: np.ndarray
    agent_mask: np.ndarray
    lane: np.ndarray
    anchor_xy: np.ndarray

    def agent_input(self) -> np.ndarray:
        """Flattened per-agent input (B, A, H * 5 + 6): history then static features."""
        b, a = self.agent_hist.shape[:2]
        return np.concatenate([self.agent_hist.reshape(b, a, -1), self.agent_static], axis=2)


def _lane_offset_and_index(y_m: np.ndarray, marking_y_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Offset from the lane centre [m] and lane index for y (B,), NaN / -1 without lanes."""
    centres = lane_centres_m(marking_y_m)
    idx = lane_index_of(y_m, marking_y_m)
    if centres.shape[1] == 0:
        return np.full(y_m.shape, np.nan), idx
    c = np.take_along_axis(centres, np.maximum(idx, 0)[:, None], axis=1)[:, 0]
    return np.where(idx >= 0, y_m - c, np.nan), idx


def scene_features(batch: ScenarioBatch) -> SceneFeatures:
    """The model inputs of ``batch`` from frames <= ``T0_INDEX`` only."""
    b, n = len(batch), batch.n_neighbours
    frames = list(HIST_FRAMES)
    my = batch.marking_y_m.astype(np.float64)

    # (B, A, H, 2) positions / velocities, ego first
    xy = np.concatenate([batch.ego_xy_m[:, None, frames], batch.nbr_xy_m[:, :, frames]], axis=1).astype(np.float64)
    vxy = np.concatenate([batch.ego_vxy_mps[:, None, frames], batch.nbr_vxy_mps[:, :, frames]],
                         axis=1).astype(np.float64)
    valid = np.concatenate([np.ones((b, 1, len(frames)), dtype=bool), batch.nbr_valid[:, :, frames]], axis=1)
    valid &= np.isfinite(xy).all(axis=-1) & np.isfinite(vxy).all(axis=-1)
    hist = np.stack([xy[..., 0] / SCALE_X_M, xy[..., 1] / SCALE_Y_M, vxy[..., 0] / SCALE_VX_MPS,
                     vxy[..., 1] / SCALE_VY_MPS, np.ones_like(xy[..., 0])], axis=-1)
    hist = np.where(valid[..., None], hist, 0.0)

    mask = np.concatenate([np.ones((b, 1), dtype=bool), valid[:, 1:, -1]], axis=1)
    length = np.concatenate([batch.ego_length_m[:, None], batch.nbr_length_m], axis=1).astype(np.float64)
    width = np.concatenate([batch.ego_width_m[:, None], batch.nbr_width_m], axis=1).astype(np.float64)
    cls = np.concatenate([batch.ego_class[:, None], batch.nbr_class], axis=1)
    is_ego = np.zeros((b, 1 + n))
    is_ego[:, 0] = 1.0

    y0 = np.where(mask, xy[:, :, -1, 1], 0.0)  # (B, A) y at t = 0
    _, ego_idx = _lane_offset_and_index(y0[:, 0], my)
    offsets = np.empty((b, 1 + n))
    rel_lane = np.empty((b, 1 + n))
    for a in range(1 + n):
        off, idx = _lane_offset_and_index(y0[:, a], my)
        offsets[:, a] = off
        rel_lane[:, a] = np.where((idx >= 0) & (ego_idx >= 0), idx - ego_idx, 0)
    offsets = np.where(mask & np.isfinite(offsets), offsets / 2.0, 0.0)
    rel_lane = np.where(mask, rel_lane, 0.0)
    static = np.stack([np.nan_to_num(length) / 5.0, np.nan_to_num(width) / 2.0,
                       (cls == VEHICLE_CLASS_TRUCK).astype(np.float64), is_ego, offsets, rel_lane], axis=-1)
    static = np.where(mask[..., None], static, 0.0)

    m = min(my.shape[1], MAX_MARKINGS)
    lane = np.zeros((b, N_LANE_FEATURES))
    known = np.isfinite(my[:, :m])
    lane[:, :m] = np.where(known, (my[:, :m] - np.nan_to_num(xy[:, 0, -1, 1])[:, None]) / SCALE_Y_M, 0.0)
    kind = np.where(batch.marking_is_edge[:, :m], 1.0, -1.0)
    lane[:, MAX_MARKINGS : MAX_MARKINGS + m] = np.where(known, kind, 0.0)
    n_lanes = np.maximum(known.sum(axis=1) - 1, 0)
    lane[:, 2 * MAX_MARKINGS] = lane_width_m(my) / 4.0
    has = ego_idx >= 0
    lane[:, 2 * MAX_MARKINGS + 1] = np.where(has, (n_lanes - 1 - ego_idx) / 3.0, 0.0)
    lane[:, 2 * MAX_MARKINGS + 2] = np.where(has, ego_idx / 3.0, 0.0)
    limit = batch.speed_limit_mps.astype(np.float64)
    lane[:, 2 * MAX_MARKINGS + 3] = np.where(np.isfinite(limit), limit / 40.0, 0.0)
    anchor = KinematicGoalPredictor().predict_goals(batch).top
    vx0 = np.nan_to_num(vxy[:, 0, -1, 0])
    lane[:, 2 * MAX_MARKINGS + 4] = (anchor[:, 0] - vx0 * HORIZON_S) / 10.0
    lane[:, 2 * MAX_MARKINGS + 5] = anchor[:, 1] / SCALE_Y_M
    return SceneFeatures(agent_hist=hist, agent_static=static, agent_mask=mask, lane=lane, anchor_xy=anchor)
