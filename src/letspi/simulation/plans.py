"""What both closed-loop simulators (SUMO's lockstep and the log replay) do with plans: record every
plan made (``PlanLog``) and turn a replan into the ego's commands (``follow_plans``)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from letspi.constants import DT_S, N_TOTAL, T0_INDEX
from letspi.simulation.config import OFF_ROAD_MARGIN_M, ClosedLoopConfig
from letspi.simulation.replan import Replan


class PlanLog:
    """Every plan made, per scenario and replanning slot: xy (K, R, F, 2), goals (K, R, 2), info (per-replan extras,
    each (K, R)) and plan_s (planner wall time summed over the replans) [s]."""

    def __init__(self, k: int, frames: Sequence[int]) -> None:
        self.frames = list(frames)
        self.slot = {f: i for i, f in enumerate(self.frames)}
        n_future = N_TOTAL - T0_INDEX - 1
        self.xy = np.full((k, len(self.frames), n_future, 2), np.nan)
        self.goals = np.full((k, len(self.frames), 2), np.nan)
        self.info: dict[str, np.ndarray] = {}
        self.plan_s = 0.0

    def add(self, f: int, replan: Replan) -> None:
        i = self.slot[f]
        rows = np.asarray(replan.rows, dtype=np.int64)
        self.xy[rows, i] = replan.xy_m
        self.goals[rows, i] = replan.goals_xy_m
        for key, arr in replan.info.items():
            self.info.setdefault(key, np.full(self.goals.shape[:2], np.nan))[rows, i] = arr
        self.plan_s += replan.plan_s


def follow_plans(
    replan: Replan, f: int, ego_xy_m: np.ndarray, ego_vxy_mps: np.ndarray, road_y_m: np.ndarray,
    config: ClosedLoopConfig, cmd_xy_m: np.ndarray, cmd_vxy_mps: np.ndarray, nonfinite: np.ndarray,
) -> None:  # fmt: skip
    """The ego commands of the scenarios that replanned at frame f, up to each plan's last frame (in place).
    ego_xy_m, ego_vxy_mps: (K, 2) the ego at f; road_y_m: (K, 2) road edges; cmd_xy_m, cmd_vxy_mps: (K, T, 2),
    written for f + 1 .. follow_until; nonfinite: (K,) set where a plan is not finite or leaves the simulated area:
    the ego keeps its velocity instead."""
    rows = np.asarray(replan.rows, dtype=np.int64)
    until = np.asarray(replan.follow_until, dtype=np.int64)
    for stop in np.unique(until).tolist():
        sel = until == stop
        r = rows[sel]
        n_use = stop - f
        use_xy = replan.xy_m[sel, :n_use].copy()
        use_vxy = replan.vxy_mps[sel, :n_use].copy()
        bad = ~(np.isfinite(use_xy).all(axis=(1, 2)) & np.isfinite(use_vxy).all(axis=(1, 2)))
        with np.errstate(invalid="ignore"):
            bad |= ~inside_simulated_area(use_xy, road_y_m[r], config).all(axis=1)
        if bad.any():
            nonfinite[r[bad]] = True
            centre = ego_xy_m[r[bad]]
            v0 = ego_vxy_mps[r[bad]]
            steps = np.arange(1, n_use + 1)[None, :, None] * DT_S
            use_xy[bad] = centre[:, None, :] + v0[:, None, :] * steps
            use_vxy[bad] = v0[:, None, :]
        cmd_xy_m[r, f + 1 : stop + 1] = use_xy
        cmd_vxy_mps[r, f + 1 : stop + 1] = use_vxy


def inside_simulated_area(xy: np.ndarray, road_y: np.ndarray, config: ClosedLoopConfig) -> np.ndarray:
    """(K, S) whether planned positions (K, S, 2) lie on the road's length and within ``OFF_ROAD_MARGIN_M`` of its
    edges (further out SUMO cannot place a vehicle sensibly)."""
    x_ok = (xy[..., 0] > -config.road_behind_m + 50.0) & (xy[..., 0] < config.road_ahead_m - 50.0)
    y_ok = (xy[..., 1] > road_y[:, :1] - OFF_ROAD_MARGIN_M) & (xy[..., 1] < road_y[:, 1:] + OFF_ROAD_MARGIN_M)
    return np.asarray(x_ok & y_ok)
