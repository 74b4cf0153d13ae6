"""``mobil`` goals: where a rule-based driver (IDM car following, MOBIL lane choice) would be at the horizon.

Kesting, Treiber & Helbing (2007) with politeness 0, as highway-env's vehicles drive: the ego moves to an
adjacent lane when its IDM acceleration there beats the current lane's by ``gain_threshold_mps2`` and the new
follower need not brake harder than ``max_imposed_decel_mps2``. A lane change already under way (the lane of
``y0 + vy0 * lateral_lookahead_s``) is kept. The goal's x is the end of an IDM rollout behind the chosen lane's
leader (constant speed); its y is that lane's centre. Everything is read at t = 0; nothing of the future.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from letspi.constants import DT_S, HORIZON_S, T0_INDEX
from letspi.physics.goals import GoalPrediction
from letspi.physics.idm import CAR_IDM, IdmKernel, IdmParams, desired_speed_from_history, step_speed
from letspi.scenario.queries import OFF_ROAD, lane_centres_y_m, lane_index_of
from letspi.scenario.types import ScenarioBatch

NO_LANE = -1


@dataclass(frozen=True)
class LaneGaps:
    """Leader and follower of the ego in one lane at t = 0, (B,) each: bumper gaps [m] (inf: none) and speeds
    [m/s] (NaN: none)."""

    lead_gap_m: np.ndarray
    lead_speed_mps: np.ndarray
    follow_gap_m: np.ndarray
    follow_speed_mps: np.ndarray


def lane_gaps(batch: ScenarioBatch, lane: np.ndarray) -> LaneGaps:
    """The ego's leader and follower in lane index ``lane`` (B,) (0 = rightmost; ``NO_LANE``: none found)."""
    ex = batch.ego_xy0_m[:, 0].astype(np.float64)
    nxy = batch.nbr_xy_m[:, :, T0_INDEX].astype(np.float64)  # (B, N, 2)
    nvx = batch.nbr_vxy_mps[:, :, T0_INDEX, 0].astype(np.float64)
    valid = batch.nbr_valid[:, :, T0_INDEX] & np.isfinite(nxy).all(axis=-1)
    in_lane = valid & (lane_index_of(batch.marking_y_m, nxy[..., 1]) == lane[:, None]) & (lane[:, None] != NO_LANE)
    dx = nxy[..., 0] - ex[:, None]
    half = 0.5 * (batch.nbr_length_m.astype(np.float64) + batch.ego_length_m.astype(np.float64)[:, None])
    ahead, behind = in_lane & (dx >= 0), in_lane & (dx < 0)
    lead_dx = np.where(ahead, dx, np.inf)
    follow_dx = np.where(behind, -dx, np.inf)
    lead, follow = np.argmin(lead_dx, axis=1), np.argmin(follow_dx, axis=1)
    rows = np.arange(len(batch))
    has_lead, has_follow = np.isfinite(lead_dx[rows, lead]), np.isfinite(follow_dx[rows, follow])
    return LaneGaps(
        lead_gap_m=np.where(has_lead, lead_dx[rows, lead] - half[rows, lead], np.inf),
        lead_speed_mps=np.where(has_lead, nvx[rows, lead], np.nan),
        follow_gap_m=np.where(has_follow, follow_dx[rows, follow] - half[rows, follow], np.inf),
        follow_speed_mps=np.where(has_follow, nvx[rows, follow], np.nan))


@dataclass(frozen=True)
class MobilGoalPredictor:
    """IDM + MOBIL goals (module docstring), K = 1. The desired speed is the speed limit where there is one,
    else the highest speed of the history."""

    gain_threshold_mps2: float = 0.2
    max_imposed_decel_mps2: float = 2.0
    lateral_lookahead_s: float = 1.5
    horizon_s: float = HORIZON_S
    idm: IdmParams = CAR_IDM

    def desired_speed_mps(self, batch: ScenarioBatch) -> np.ndarray:
        history = np.hypot(batch.ego_vxy_mps[:, : T0_INDEX + 1, 0], batch.ego_vxy_mps[:, : T0_INDEX + 1, 1])
        limit = batch.speed_limit_mps.astype(np.float64)
        return np.where(np.isfinite(limit) & (limit > 0), limit, desired_speed_from_history(history))

    def choose_lanes(self, batch: ScenarioBatch) -> np.ndarray:
        """Lane index (B,) the ego drives in at the horizon (0 = rightmost; ``NO_LANE`` off the road)."""
        y0 = batch.ego_xy0_m[:, 1].astype(np.float64)
        vy0 = batch.ego_vxy0_mps[:, 1].astype(np.float64)
        v0 = np.maximum(batch.ego_vxy0_mps[:, 0].astype(np.float64), 0.0)
        here = lane_index_of(batch.marking_y_m, y0[:, None])[:, 0]
        heading = lane_index_of(batch.marking_y_m, (y0 + vy0 * self.lateral_lookahead_s)[:, None])[:, 0]
        n_lanes = np.isfinite(lane_centres_y_m(batch)).sum(axis=1)
        ego_idm = IdmKernel(self.desired_speed_mps(batch), self.idm)

        def ego_accel(lane: np.ndarray) -> tuple[np.ndarray, LaneGaps]:
            gaps = lane_gaps(batch, lane)
            return ego_idm(v0, gaps.lead_gap_m, gaps.lead_speed_mps), gaps

        acc_here, _ = ego_accel(here)
        best, best_gain = here.copy(), np.full(len(batch), self.gain_threshold_mps2)
        for side in (1, -1):  # left (+y) first: a tie overtakes on the left
            lane = here + side
            exists = (here != OFF_ROAD) & (lane >= 0) & (lane < n_lanes)
            lane = np.where(exists, lane, NO_LANE)
            acc, gaps = ego_accel(lane)
            follower = IdmKernel(np.maximum(np.nan_to_num(gaps.follow_speed_mps), 1.0), self.idm)
            imposed = follower(np.nan_to_num(gaps.follow_speed_mps), gaps.follow_gap_m, v0)
            safe = (gaps.lead_gap_m > 0) & (gaps.follow_gap_m > 0) & (imposed >= -self.max_imposed_decel_mps2)
            gain = acc - acc_here
            better = exists & safe & (gain > best_gain)
            best, best_gain = np.where(better, lane, best), np.where(better, gain, best_gain)
        under_way = (heading != OFF_ROAD) & (heading != here) & (here != OFF_ROAD)
        return np.where(under_way, heading, best)

    def predict_goals(self, batch: ScenarioBatch) -> GoalPrediction:
        lane = self.choose_lanes(batch)
        centres = np.nan_to_num(lane_centres_y_m(batch), nan=0.0)
        y0 = batch.ego_xy0_m[:, 1].astype(np.float64)
        goal_y = np.where(lane == NO_LANE, y0, np.take_along_axis(centres, np.maximum(lane, 0)[:, None], 1)[:, 0])
        gaps = lane_gaps(batch, lane)
        ego_idm = IdmKernel(self.desired_speed_mps(batch), self.idm)
        speed = np.maximum(batch.ego_vxy0_mps[:, 0].astype(np.float64), 0.0)
        lead_speed = np.nan_to_num(gaps.lead_speed_mps)
        gap, travelled = gaps.lead_gap_m.copy(), np.zeros(len(batch))
        for _ in range(round(self.horizon_s / DT_S)):
            speed_next = step_speed(speed, ego_idm(speed, gap, lead_speed), DT_S)
            step_m = 0.5 * (speed + speed_next) * DT_S
            travelled += step_m
            gap = gap + lead_speed * DT_S - step_m
            speed = speed_next
        goal_x = batch.ego_xy0_m[:, 0].astype(np.float64) + travelled
        return GoalPrediction(goals_xy_m=np.stack([goal_x, goal_y], axis=1)[:, None, :], probs=np.ones((len(batch), 1)))
