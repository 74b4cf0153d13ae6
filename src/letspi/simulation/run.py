"""``run_closed_loop``: closed-loop simulation of a batch, in-process, in worker processes or on Ray.

The batch is cut into chunks of one lane layout, each simulated in lockstep; chunks are yielded in
completion order with their scenarios' positions in the batch, so a caller can write and resume per chunk.
"""

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


def run_closed_loop(
    planner_spec: PlannerSpecLike,
    batch: ScenarioBatch,
    config: ClosedLoopConfig | None = None,
    *,
    indices: Sequence[int] | np.ndarray | None = None,
    max_worker_restarts: int = 2,
    scripted_nbr: np.ndarray | None = None,
) -> Generator[ClosedLoopChunk, None, None]:
    """Simulate ``batch`` (or its rows ``indices``) closed loop; yield one ``ClosedLoopChunk`` per chunk.

    A caller that stops early (Ctrl-C while it writes a chunk) closes the generator
    (``contextlib.closing``): worker processes and Ray actors stop at once, not when it is collected.

    planner_spec: a ``PlannerSpec`` (built inside each worker) or a ``BuiltPlanner`` (used as is).
    config: the run (default ``ClosedLoopConfig()``), this planner's period applied (``for_planner``);
    ``workers`` processes, or actors on Ray (``ray_address``: "local" unless Ray runs, "auto" or an address).
    max_worker_restarts: workers that may die and be replaced before the run fails (their unfinished
    chunks are simulated again: nothing is lost or duplicated).
    scripted_nbr: (B, N) bool over ``batch``: neighbour slots that replay their log throughout in
    ``closed-loop-hybrid``; None = none.
    """
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
