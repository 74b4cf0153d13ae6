"""``run_closed_loop``: closed-loop simulation of a batch, in-process, in worker processes or on Ray.

The batch is cut into chunks of scenarios with one lane layout (``ClosedLoopConfig.chunk_size``
at most); each chunk is simulated in lockstep by one SUMO instance (``letspi.simulation.engine``).
Chunks are yielded as they finish (completion order, not batch order), each with the positions
of its scenarios in the batch, so a caller can write and resume per chunk
(``letspi.simulation.store``).

Workers: ``workers=0`` runs in this process; ``workers=N`` starts N processes (spawned: a fresh
interpreter, one libsumo each), each building its planner once from the picklable planner spec;
``ray_address`` runs the same work on Ray actors (``letspi.simulation.ray_backend``).
"""

from __future__ import annotations

from collections.abc import Generator, Sequence
from dataclasses import replace

import numpy as np

from letspi.scenario.types import ScenarioBatch
from letspi.simulation.config import ClosedLoopConfig, ClosedLoopMode
from letspi.simulation.pool import run_in_processes
from letspi.simulation.ray_backend import run_on_ray
from letspi.simulation.result import ClosedLoopChunk
from letspi.simulation.spec import PlannerSpecLike, spec_replan_s
from letspi.simulation.worker import ChunkWorker, make_tasks


def effective_config(
    planner_spec: PlannerSpecLike, mode: ClosedLoopMode | str, replan_s: float | None, config: ClosedLoopConfig | None
) -> ClosedLoopConfig:
    """The run's configuration: ``replan_s`` argument > the planner's own > ``config.replan_s``."""
    base = config or ClosedLoopConfig()
    own = spec_replan_s(planner_spec)
    period = replan_s if replan_s is not None else (own if own is not None else base.replan_s)
    return replace(base, mode=ClosedLoopMode(mode), replan_s=float(period))


def run_closed_loop(
    planner_spec: PlannerSpecLike,
    batch: ScenarioBatch,
    mode: ClosedLoopMode | str = ClosedLoopMode.LOG,
    *,
    replan_s: float | None = None,
    workers: int = 0,
    config: ClosedLoopConfig | None = None,
    indices: Sequence[int] | np.ndarray | None = None,
    ray_address: str | None = None,
    max_worker_restarts: int = 2,
    scripted_nbr: np.ndarray | None = None,
) -> Generator[ClosedLoopChunk, None, None]:
    """Simulate ``batch`` (or its rows ``indices``) closed loop; yield one ``ClosedLoopChunk`` per chunk.

    A caller that stops early (Ctrl-C while it writes a chunk) closes the generator
    (``contextlib.closing``): worker processes and Ray actors stop at once, not when it is collected.

    planner_spec: a ``PlannerSpec`` (built inside each worker) or a picklable planner object.
    mode: ``closed-loop-log``, ``closed-loop-reactive`` or ``closed-loop-hybrid`` (``ClosedLoopMode``).
    replan_s: replanning period [s]
    (default: the planner spec's own, else ``config.replan_s``, 1.0). workers: 0 = this process,
    N >= 1 = N worker processes. ray_address: run on Ray instead ("local" starts a local instance
    unless Ray is already initialised, "auto" or an address joins a cluster); ``workers`` actors.
    max_worker_restarts: worker processes (or actors) that may die and be replaced before the run
    fails; their unfinished chunks are simulated again, so nothing is lost or duplicated.
    scripted_nbr: (B, N) bool over ``batch``: neighbour slots that keep their recorded (scripted)
    behaviour in ``closed-loop-hybrid`` (``letspi.scenario.scripted.scripted_neighbours``); None = none.
    """
    cfg = effective_config(planner_spec, mode, replan_s, config)
    if workers < 0:
        raise ValueError(f"workers must be >= 0, got {workers}")
    tasks = make_tasks(batch, cfg, indices, scripted_nbr)
    if not tasks:
        return
    if ray_address is not None:
        yield from run_on_ray(planner_spec, tasks, cfg, max(1, workers), ray_address, max_worker_restarts)
        return
    if workers == 0:
        worker = ChunkWorker(planner_spec, cfg)
        try:
            for task in tasks:
                yield worker.run(task)
        finally:
            worker.close()
        return
    yield from run_in_processes(planner_spec, tasks, cfg, workers, max_worker_restarts)

