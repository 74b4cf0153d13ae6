"""Chunks of work and the worker that simulates them (one planner + one SUMO session per process)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from letspi.llm.client import ParamAdvisor
from letspi.llm.spec import default_concurrency
from letspi.planners.base import ModelPlanner, Planner
from letspi.scenario.types import ScenarioBatch
from letspi.simulation.config import ClosedLoopConfig
from letspi.simulation.dual_rate import DualRateReplanner
from letspi.simulation.engine import simulate_group
from letspi.simulation.network import layout_keys
from letspi.simulation.replan import Closing, FuturePolicy, PeriodicReplanner, Replanner
from letspi.simulation.replay import simulate_replay_group
from letspi.simulation.result import ClosedLoopChunk
from letspi.simulation.schedule import DualRatePlanner
from letspi.simulation.session import SumoSession
from letspi.simulation.spec import PlannerSpecLike, build_planner, reads_recorded_future, runs_dual_rate


@dataclass(frozen=True)
class ChunkTask:
    """One unit of work: scenarios ``indices`` of the run's batch, taken (``batch``); ``scripted_nbr`` (K, N) bool."""

    task_id: int
    indices: np.ndarray
    batch: ScenarioBatch
    scripted_nbr: np.ndarray | None = None


def plan_chunks(
    batch: ScenarioBatch, chunk_size: int, indices: Sequence[int] | np.ndarray | None = None
) -> list[np.ndarray]:
    """Scenario positions grouped by lane layout (batch order within a layout), cut into chunks."""
    idx = np.arange(len(batch)) if indices is None else np.asarray(indices, dtype=np.int64)
    if idx.size == 0:
        return []
    keys = layout_keys(batch.marking_y_m[idx])
    order: dict[tuple[float, ...], list[int]] = {}
    for i, key in zip(idx.tolist(), keys, strict=True):
        order.setdefault(key, []).append(i)
    chunks: list[np.ndarray] = []
    for members in order.values():
        arr = np.asarray(members, dtype=np.int64)
        chunks.extend(arr[s : s + chunk_size] for s in range(0, len(arr), chunk_size))
    return chunks


def llm_concurrency(planner: Planner) -> int:
    """LLM calls a dual-rate planner keeps in flight: its backend's ``default_concurrency``, 1 without an LLM."""
    advisor = planner.advisor if isinstance(planner, ModelPlanner) else None
    return default_concurrency(advisor.backend.spec) if isinstance(advisor, ParamAdvisor) else 1


def replanner_for(planner: Planner, batch: ScenarioBatch, config: ClosedLoopConfig, future: FuturePolicy,
                  dual_rate: bool = False) -> Replanner:
    """The replanning step of a lockstep group: dual rate (``config.dual_rate``) if ``dual_rate``, else periodic."""
    if dual_rate:
        if not isinstance(planner, DualRatePlanner):
            raise TypeError(f"planner {planner.name!r} runs dual-rate but is no DualRatePlanner (its table entry "
                            "says dual_rate)")
        return DualRateReplanner(planner, batch, config.replan_frames, future, config.dual_rate,
                                 concurrency=llm_concurrency(planner))
    return PeriodicReplanner(planner, batch, config.replan_frames, future)


def simulate_chunk(
    session: SumoSession, planner: Planner, task: ChunkTask, config: ClosedLoopConfig, future: FuturePolicy,
    dual_rate: bool = False,
) -> ClosedLoopChunk:
    """Simulate one chunk (any layouts: one lockstep group per layout) and label it with batch indices.
    ``config.uses_sumo``: in SUMO (``session``), else the log replay (``session`` unused, never started)."""
    keys = layout_keys(task.batch.marking_y_m)
    parts: list[ClosedLoopChunk] = []
    rows_all: list[np.ndarray] = []
    for key in dict.fromkeys(keys):
        rows = np.asarray([i for i, k in enumerate(keys) if k == key], dtype=np.int64)
        group = task.batch.take(rows)
        replanner = replanner_for(planner, group, config, future, dual_rate)
        try:
            if config.uses_sumo:
                part = simulate_group(session, planner, group, config, future=future,
                                      run_tag=f"t{task.task_id}.{len(parts)}",
                                      scripted_nbr=None if task.scripted_nbr is None else task.scripted_nbr[rows],
                                      replanner=replanner)
            else:
                part = simulate_replay_group(planner, group, config, future=future, replanner=replanner)
        finally:
            if isinstance(replanner, Closing):
                replanner.close()  # LLM calls still outstanding are dropped
        parts.append(part)
        rows_all.append(rows)
    out = parts[0] if len(parts) == 1 else ClosedLoopChunk.concat(parts)
    rows = np.concatenate(rows_all)
    return replace(out, indices=np.asarray(task.indices)[rows])


class ChunkWorker:
    """A planner and a SUMO session (started at its first SUMO chunk), built once per process, chunk after chunk."""

    def __init__(self, planner_spec: PlannerSpecLike, config: ClosedLoopConfig) -> None:
        self.config = config
        self.planner = build_planner(planner_spec)
        self.future: FuturePolicy = "log" if reads_recorded_future(planner_spec) else "none"
        self.dual_rate = runs_dual_rate(planner_spec)
        self.session = SumoSession(config)

    def run(self, task: ChunkTask) -> ClosedLoopChunk:
        return simulate_chunk(self.session, self.planner, task, self.config, self.future, self.dual_rate)

    def close(self) -> None:
        self.session.close()


def make_tasks(
    batch: ScenarioBatch, config: ClosedLoopConfig, indices: Sequence[int] | np.ndarray | None = None,
    scripted_nbr: np.ndarray | None = None, dual_rate: bool = False,
) -> list[ChunkTask]:
    """The run's chunks (``config.scenarios_per_chunk(dual_rate)`` scenarios at most); ``scripted_nbr`` (B, N)."""
    if scripted_nbr is not None and np.shape(scripted_nbr) != (len(batch), batch.n_neighbours):
        raise ValueError(f"scripted_nbr must be (B, N) = {(len(batch), batch.n_neighbours)}, "
                         f"got {np.shape(scripted_nbr)}")
    return [
        ChunkTask(task_id=i, indices=rows, batch=batch.take(rows),
                  scripted_nbr=None if scripted_nbr is None else np.asarray(scripted_nbr, dtype=bool)[rows])
        for i, rows in enumerate(plan_chunks(batch, config.scenarios_per_chunk(dual_rate), indices))
    ]
