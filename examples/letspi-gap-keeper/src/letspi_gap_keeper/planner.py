"""The gap keeper: stays in its lane and keeps a time gap to the vehicle ahead (a plain cruise control).

It sees what letspi gives every planner at t = 0: the ego's and the neighbours' history in the ego
frame (x along the road, ego at the origin at t = 0). Vectorised over the batch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from letspi.plugin import DT_S, N_FUTURE, T0_INDEX, PlanBatch, ScenarioBatch


@dataclass
class GapKeeperPlanner:
    """Follows the in-lane leader at ``time_gap_s`` (plus ``standstill_m``), predicting it at constant
    speed; without a leader it holds its speed. Acceleration within [-``max_brake_mps2``, 1.5] m/s²."""

    time_gap_s: float = 1.5
    standstill_m: float = 2.0
    max_brake_mps2: float = 6.0
    name: str = "gap-keeper"
    batch_size: int = 4096
    reads_future: bool = False  # it plans from the history only

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        xy0 = batch.ego_xy_m[:, T0_INDEX].astype(np.float64)  # (B, 2)
        v0 = np.maximum(batch.ego_vxy_mps[:, T0_INDEX, 0].astype(np.float64), 0.0)  # (B,)
        gap_m, lead_v = self._leader(batch, xy0)  # (B,), NaN without a leader
        x, v = xy0[:, 0].copy(), v0.copy()
        xs, vs = np.empty((len(v0), N_FUTURE)), np.empty((len(v0), N_FUTURE))
        has_leader = np.isfinite(gap_m)
        gap = np.where(has_leader, gap_m, np.inf)
        for k in range(N_FUTURE):  # a linear spacing controller, clipped to comfortable limits
            wanted = self.standstill_m + self.time_gap_s * v
            lead = np.where(has_leader, np.nan_to_num(lead_v), v)
            acc = np.where(has_leader, 0.25 * (gap - wanted) + 0.6 * (lead - v), 0.0)
            acc = np.clip(acc, -self.max_brake_mps2, 1.5)
            v_next = np.maximum(v + acc * DT_S, 0.0)
            x = x + 0.5 * (v + v_next) * DT_S
            gap = gap + (lead - 0.5 * (v + v_next)) * DT_S
            v = v_next
            xs[:, k], vs[:, k] = x, v
        y = np.broadcast_to(xy0[:, 1:2], xs.shape)
        plan_xy = np.stack([xs, y], axis=-1)
        plan_v = np.stack([vs, np.zeros_like(vs)], axis=-1)
        return PlanBatch(xy_m=plan_xy, vxy_mps=plan_v, goals_xy_m=plan_xy[:, -1].copy(),
                         info={"gap_keeper_leader": has_leader})

    @staticmethod
    def _leader(batch: ScenarioBatch, xy0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bumper gap [m] and speed [m/s] of the nearest vehicle ahead whose box overlaps the ego's lane
        band at t = 0 (B,), NaN where there is none."""
        valid = batch.nbr_valid[:, :, T0_INDEX]  # (B, N)
        nxy = batch.nbr_xy_m[:, :, T0_INDEX].astype(np.float64)  # (B, N, 2)
        dx = nxy[..., 0] - xy0[:, None, 0]
        half_widths = 0.5 * (batch.nbr_width_m + batch.ego_width_m[:, None])
        in_lane = np.abs(nxy[..., 1] - xy0[:, None, 1]) < half_widths
        gap = dx - 0.5 * (batch.nbr_length_m + batch.ego_length_m[:, None])
        ahead = valid & in_lane & (dx > 0)
        gap = np.where(ahead, gap, np.inf)
        nearest = np.argmin(gap, axis=1)
        rows = np.arange(len(gap))
        found = np.isfinite(gap[rows, nearest])
        lead_v = batch.nbr_vxy_mps[rows, nearest, T0_INDEX, 0].astype(np.float64)
        return np.where(found, np.maximum(gap[rows, nearest], 0.0), np.nan), np.where(found, lead_v, np.nan)
