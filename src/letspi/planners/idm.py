"""``idm``: the paper's longitudinal baseline: the ego follows its in-lane leader with IDM. Laterally it settles,
critically damped, into the lane of ``y0 + vy0 · LATERAL_LOOKAHEAD_S`` (frozen y would stop a lane change at once).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from letspi.constants import DT_S, N_FUTURE
from letspi.keyed import Config
from letspi.physics.idm import rollout_idm_ego
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.planners.base import PlanBatch
from letspi.planners.config import NEIGHBOURS
from letspi.planners.options import PlannerOption
from letspi.scenario.queries import OFF_ROAD, lane_centres_y_m, lane_index_of
from letspi.scenario.types import ScenarioBatch

LATERAL_LOOKAHEAD_S = 1.5
LATERAL_TIME_CONSTANT_S = 0.8
OPTIONS: tuple[PlannerOption[Any], ...] = (NEIGHBOURS,)


def settle_laterally(batch: ScenarioBatch) -> tuple[np.ndarray, np.ndarray]:
    """Lateral position and speed (B, F) settling into the lane the ego is heading for."""
    y0 = batch.ego_xy0_m[:, 1].astype(np.float64)
    vy0 = batch.ego_vxy0_mps[:, 1].astype(np.float64)
    centres = lane_centres_y_m(batch)  # (B, L) NaN padded
    n_lanes = np.sum(np.isfinite(centres), axis=1)
    heading = lane_index_of(batch.marking_y_m, (y0 + vy0 * LATERAL_LOOKAHEAD_S)[:, None])[:, 0]
    here = lane_index_of(batch.marking_y_m, y0[:, None])[:, 0]
    lane = np.where(heading == OFF_ROAD, here, heading)
    lane = np.clip(lane, 0, np.maximum(n_lanes - 1, 0))
    target = np.take_along_axis(np.nan_to_num(centres, nan=0.0), lane[:, None], axis=1)[:, 0]
    target = np.where((lane == OFF_ROAD) | (n_lanes == 0), y0, target)
    t_s = np.arange(1, N_FUTURE + 1) * DT_S  # (F,)
    tc = LATERAL_TIME_CONSTANT_S
    c1 = (y0 - target)[:, None]
    c2 = (vy0 + (y0 - target) / tc)[:, None]
    decay = np.exp(-t_s / tc)[None, :]
    y = target[:, None] + (c1 + c2 * t_s[None, :]) * decay
    vy = (c2 - (c1 + c2 * t_s[None, :]) / tc) * decay
    return y, vy


class IdmConfig(Config):
    kind: Literal["idm"] = "idm"
    neighbours: NeighbourPredictionMode = NeighbourPredictionMode.IDM


@dataclass
class IdmPlanner:
    neighbour_mode: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    name: str = "idm"
    batch_size: int = 4096

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        roll = rollout_idm_ego(batch, predict_neighbours(batch, self.neighbour_mode))
        xy = np.array(roll.xy_m, dtype=np.float64)
        vxy = np.array(roll.vxy_mps, dtype=np.float64)
        xy[..., 1], vxy[..., 1] = settle_laterally(batch)
        # IDM has no goal: its own endpoint stands in, so success checks feasibility and safety only
        return PlanBatch(xy_m=xy, vxy_mps=vxy, goals_xy_m=xy[:, -1].copy())
