"""``run_closed_loop``: closed-loop simulation of a batch, in-process, in worker processes or on Ray."""

from __future__ import annotations

from collections.abc import Generator, Sequence

import numpy as np

from letspi.scenario.types import ScenarioBatch
from letspi.simulation.config import ClosedLoopConfig
from letspi.simulation.pool import run_in_processes
from letspi.simulation.ray_backend import run_on_ray
from letspi.simulation.result import ClosedLoopChunk
from letspi.simulation.spec import PlannerSpecLike, runs_dual_rate, spec_name
from letspi.simulation.worker import ChunkWorker, make_tasks


def run_closed_loop(planner_spec: PlannerSpecLike, batch: ScenarioBatch, config: ClosedLoopConfig | None = None, *,
                    indices: Sequence[int] | np.ndarray | None = None, max_worker_restarts: int = 2,
                    scripted_nbr: np.ndarray | None = None) -> Generator[ClosedLoopChunk, None, None]:
    """Simulate ``batch`` (or its rows ``indices``) closed loop; yield ``ClosedLoopChunk``s in completion order,
    chunks of one lane layout. Close the generator to stop workers at once (``contextlib.closing``). planner_spec: a
    ``PlannerSpec`` (built in each worker) or a ``BuiltPlanner`` (used as is). config: default
    ``ClosedLoopConfig()``, this planner's period applied. max_worker_restarts: workers that may die before the run
    fails (their chunks are simulated again). scripted_nbr: (B, N) bool, slots that replay their log in
    ``closed-loop-hybrid``."""
    cfg = (config or ClosedLoopConfig()).for_planner(spec_name(planner_spec))
    tasks = make_tasks(batch, cfg, indices, scripted_nbr, dual_rate=runs_dual_rate(planner_spec))
    if not tasks:
        return
    if cfg.ray_address is not None:
        yield from run_on_ray(planner_spec, tasks, cfg, max(1, cfg.workers), cfg.ray_address, max_worker_restarts)
        return
    if cfg.workers == 0:
        worker = ChunkWorker(planner_spec, cfg)
        try:
            for task in tasks:
                yield worker.run(task)
        finally:
            worker.close()
        return
    yield from run_in_processes(planner_spec, tasks, cfg, cfg.workers, max_worker_restarts)
