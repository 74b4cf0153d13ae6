"""``closed-loop-log`` without SUMO, which would only echo the positions it is given: the same ``ClosedLoopChunk`` in
NumPy, with the same replanning step and ``follow_plans``, but no SUMO contact check (``simulator="replay"``)."""

from __future__ import annotations

import time

import numpy as np

from letspi.constants import DT_S, N_TOTAL, T0_INDEX
from letspi.planners.base import Planner
from letspi.scenario.types import ScenarioBatch
from letspi.simulation.config import ClosedLoopConfig, EvaluationMode
from letspi.simulation.plans import PlanLog, follow_plans
from letspi.simulation.replan import FuturePolicy, PeriodicReplanner, Replanner, SimulatedStates, lane_ids_from_y
from letspi.simulation.result import ClosedLoopChunk

__all__ = ["simulate_replay_group"]


def _replayed_neighbours(batch: ScenarioBatch) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(K, N, T, 2) xy and vxy [float64, NaN where absent], (K, N, T) valid and lane ids (0 where absent)."""
    xy = batch.nbr_xy_m.astype(np.float64)
    vxy = batch.nbr_vxy_mps.astype(np.float64)
    valid = np.asarray(batch.nbr_valid, dtype=bool) & np.isfinite(xy).all(axis=-1) & np.isfinite(vxy).all(axis=-1)
    xy = np.where(valid[..., None], xy, np.nan)
    vxy = np.where(valid[..., None], vxy, np.nan)
    lane = np.where(valid, batch.nbr_lane_id, 0).astype(batch.nbr_lane_id.dtype)
    return xy, vxy, valid, lane


def simulate_replay_group(
    planner: Planner,
    batch: ScenarioBatch,
    config: ClosedLoopConfig,
    *,
    future: FuturePolicy,
    replanner: Replanner | None = None,
) -> ClosedLoopChunk:
    """``closed-loop-log`` of K scenarios without SUMO: arguments and result as ``simulate_group``."""
    if config.mode is not EvaluationMode.LOG:
        raise ValueError(f"the replay simulates closed-loop-log only, not {config.mode.value} "
                         "(its neighbours need SUMO's driver models)")
    t_start = time.perf_counter()
    cpu_start = time.process_time()
    k = len(batch)
    nbr_xy, nbr_vxy, nbr_valid, nbr_lane = _replayed_neighbours(batch)
    log_xy = batch.ego_xy_m.astype(np.float64)
    log_vxy = batch.ego_vxy_mps.astype(np.float64)
    ego_log_valid = np.asarray(np.isfinite(log_xy).all(axis=-1) & np.isfinite(log_vxy).all(axis=-1))
    # frames after t = 0 stay NaN until simulated (a planner never sees them: ``replanning_batch``)
    ego_xy = np.full_like(log_xy, np.nan)
    ego_vxy = np.full_like(log_vxy, np.nan)
    hist = slice(0, T0_INDEX + 1)
    ego_xy[:, hist] = np.where(ego_log_valid[:, hist, None], log_xy[:, hist], np.nan)
    ego_vxy[:, hist] = np.where(ego_log_valid[:, hist, None], log_vxy[:, hist], np.nan)
    ego_lane = np.zeros_like(batch.ego_lane_id)
    ego_lane[:, hist] = np.where(ego_log_valid[:, hist], batch.ego_lane_id[:, hist], 0)
    ego_axy = batch.ego_axy_mps2.astype(np.float64).copy()
    states = SimulatedStates(ego_xy_m=ego_xy, ego_vxy_mps=ego_vxy, ego_axy_mps2=ego_axy, ego_lane_id=ego_lane,
                             nbr_xy_m=nbr_xy, nbr_vxy_mps=nbr_vxy, nbr_valid=nbr_valid, nbr_lane_id=nbr_lane)
    cmd_xy = np.full((k, N_TOTAL, 2), np.nan)
    cmd_vxy = np.full((k, N_TOTAL, 2), np.nan)
    nonfinite = np.zeros(k, dtype=bool)
    road_y = np.stack([np.nanmin(batch.marking_y_m, axis=1), np.nanmax(batch.marking_y_m, axis=1)], axis=1)
    replanner = replanner or PeriodicReplanner(planner, batch, config.replan_frames, future)
    plans = PlanLog(k, replanner.frames)
    for f in range(N_TOTAL):
        if f > T0_INDEX:  # the ego is where it was commanded (SUMO's moveToXY places it exactly)
            ego_xy[:, f] = cmd_xy[:, f]
            ego_vxy[:, f] = cmd_vxy[:, f]
            ego_axy[:, f] = (cmd_vxy[:, f] - ego_vxy[:, f - 1]) / DT_S
            ego_lane[:, f] = lane_ids_from_y(batch.marking_y_m, batch.lane_ids, ego_xy[:, f, 1:2])[:, 0]
        replan = replanner.plans(f, states)
        if replan is not None:
            plans.add(f, replan)
            follow_plans(replan, f, ego_xy[:, f], ego_vxy[:, f], road_y, config, cmd_xy, cmd_vxy, nonfinite)
    fut = slice(T0_INDEX + 1, N_TOTAL)
    n = batch.n_neighbours
    wall_s, cpu_s = time.perf_counter() - t_start, time.process_time() - cpu_start
    return ClosedLoopChunk(
        indices=np.arange(k), scenario_id=np.asarray(batch.scenario_id), planner=str(planner.name),
        mode=str(config.mode.value), replan_s=config.replan_frames * DT_S,
        ego_xy_m=ego_xy[:, fut].copy(), ego_vxy_mps=ego_vxy[:, fut].copy(),
        nbr_xy_m=nbr_xy[:, :, fut].copy(), nbr_vxy_mps=nbr_vxy[:, :, fut].copy(),
        nbr_valid=nbr_valid[:, :, fut].copy(), nbr_lane_id=nbr_lane[:, :, fut].astype(np.int8),
        nbr_handover_step=np.full((k, n), -1, dtype=np.int64),
        replan_step=np.asarray(plans.frames, dtype=np.int64) - T0_INDEX, plan_xy_m=plans.xy, plan_goal_xy_m=plans.goals,
        plan_nonfinite=nonfinite, sumo_contact=np.zeros((k, n, N_TOTAL - T0_INDEX - 1), dtype=bool),
        sumo_nbr_collisions=np.zeros(k, dtype=np.int64), plan_s=np.full(k, plans.plan_s / k),
        sim_s=np.full(k, (wall_s - plans.plan_s) / k), cpu_s=np.full(k, cpu_s / k), plan_info=plans.info,
        simulator="replay")
