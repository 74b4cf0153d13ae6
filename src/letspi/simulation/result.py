"""What a closed-loop run returns per chunk, and how it is scored with the open-loop metric code."""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from letspi.constants import T0_INDEX
from letspi.metrics.compute import ScenarioMetrics, compute_metrics
from letspi.metrics.config import MetricsConfig
from letspi.scenario.types import ScenarioBatch

#: fields of a chunk that hold one value for the run, not one per scenario
_PER_RUN = ("planner", "mode", "replan_s", "replan_step", "plan_info", "simulator")


@dataclass(frozen=True)
class ClosedLoopChunk:
    """Simulated outcome of K scenarios (F = 125 future frames, N neighbour slots, R replans); positions are box centres
    in each scenario's ego frame (origin: the ego at t = 0).

    Attributes:
        indices: (K,) positions in the batch given to ``run_closed_loop``; scenario_id: (K,) str.
        planner, mode: the planner's name and the mode; replan_s: the period used [s].
        ego_xy_m, ego_vxy_mps: (K, F, 2) the simulated ego.
        nbr_xy_m, nbr_vxy_mps: (K, N, F, 2) the neighbours, NaN when absent; nbr_valid: (K, N, F);
            nbr_lane_id: (K, N, F) HighD lane ids (0 when absent or off road).
        nbr_handover_step: (K, N) the first future step SUMO drove the neighbour; -1: it replayed its log.
        replan_step: (R,) frames after t = 0 of the plans (0, 25, ... for 1 s).
        plan_xy_m: (K, R, F, 2) every plan; plan_goal_xy_m: (K, R, 2); plan_info: extras, each (K, R).
        plan_nonfinite: (K,) a plan was not finite or left the simulated area; the ego kept its velocity.
        sumo_contact: (K, N, F) SUMO's ego contacts (all False from the replay).
        sumo_nbr_collisions: (K,) SUMO collision reports (pairs x frames) among the neighbours.
        plan_s, sim_s, cpu_s: (K,) planner wall time, the rest of the wall time and CPU time per scenario [s].
        simulator: ``sumo`` or ``replay``."""

    indices: np.ndarray
    scenario_id: np.ndarray
    planner: str
    mode: str
    replan_s: float
    ego_xy_m: np.ndarray
    ego_vxy_mps: np.ndarray
    nbr_xy_m: np.ndarray
    nbr_vxy_mps: np.ndarray
    nbr_valid: np.ndarray
    nbr_lane_id: np.ndarray
    nbr_handover_step: np.ndarray
    replan_step: np.ndarray
    plan_xy_m: np.ndarray
    plan_goal_xy_m: np.ndarray
    plan_nonfinite: np.ndarray
    sumo_contact: np.ndarray
    sumo_nbr_collisions: np.ndarray
    plan_s: np.ndarray
    sim_s: np.ndarray
    cpu_s: np.ndarray
    plan_info: dict[str, np.ndarray] = field(default_factory=dict)
    simulator: str = "sumo"

    def __len__(self) -> int:
        return len(self.indices)

    @property
    def sumo_collision(self) -> np.ndarray:
        """(K,) SUMO reported a collision of the ego in the future."""
        return np.asarray(np.asarray(self.sumo_contact).any(axis=(1, 2)))

    @property
    def sumo_collision_step(self) -> np.ndarray:
        """(K,) first future step of a SUMO-reported ego collision, -1 if none."""
        per_step: np.ndarray = np.any(self.sumo_contact, axis=1)
        return np.where(per_step.any(axis=1), per_step.argmax(axis=1), -1)

    def take(self, rows: np.ndarray) -> ClosedLoopChunk:
        """A subset of the scenarios (rows of this chunk)."""
        per_row: dict[str, Any] = {f.name: getattr(self, f.name)[rows] for f in fields(self) if f.name not in _PER_RUN}
        return replace(self, **per_row, plan_info={k: v[rows] for k, v in self.plan_info.items()})

    @staticmethod
    def concat(parts: list[ClosedLoopChunk]) -> ClosedLoopChunk:
        """Concatenate chunks of one run (same planner, mode and replanning steps)."""
        if not parts:
            raise ValueError("nothing to concatenate")
        first = parts[0]
        per_row: dict[str, Any] = {f.name: np.concatenate([getattr(p, f.name) for p in parts])
                                   for f in fields(first) if f.name not in _PER_RUN}
        info = {k: np.concatenate([p.plan_info[k] for p in parts])
                for k in first.plan_info if all(k in p.plan_info for p in parts)}
        return replace(first, **per_row, plan_info=info)


def scored_batch(batch: ScenarioBatch, chunk: ClosedLoopChunk) -> ScenarioBatch:
    """``batch``'s rows of the chunk (``chunk.indices``) with the simulated neighbour futures; the ego's recorded
    future is kept, so ADE/FDE stay distances to the log."""
    sub = batch.take(np.asarray(chunk.indices))
    fut = slice(T0_INDEX + 1, T0_INDEX + 1 + chunk.ego_xy_m.shape[1])
    nbr = {name: getattr(sub, name).copy() for name in ("nbr_xy_m", "nbr_vxy_mps", "nbr_valid", "nbr_lane_id")}
    for name, arr in nbr.items():
        arr[:, :, fut] = getattr(chunk, name)
    return replace(sub, **nbr)


def chunk_metrics(batch: ScenarioBatch, chunk: ClosedLoopChunk, config: MetricsConfig | None = None) -> ScenarioMetrics:
    """Open-loop metric code on the simulated trajectories (goal: the plan made at t = 0)."""
    goals = chunk.plan_goal_xy_m[:, 0] if chunk.plan_goal_xy_m.shape[1] else None
    return compute_metrics(scored_batch(batch, chunk), chunk.ego_xy_m, chunk.ego_vxy_mps, goals, config)
