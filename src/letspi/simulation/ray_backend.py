"""Closed-loop chunks on Ray: one long-lived actor per worker (its own planner and libsumo), one chunk at a time,
restarted and retried by Ray (``max_restarts``). Needs ``pip install 'letspi[ray]'``."""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Iterator
from types import ModuleType
from typing import Any

from letspi.execution.interrupt import on_stop, received
from letspi.simulation.config import ClosedLoopConfig
from letspi.simulation.pool import ClosedLoopWorkerError
from letspi.simulation.result import ClosedLoopChunk
from letspi.simulation.spec import PlannerSpecLike
from letspi.simulation.worker import ChunkTask, ChunkWorker


def import_ray() -> ModuleType:
    try:
        import ray
    except ImportError as exc:
        raise ClosedLoopWorkerError("running on Ray needs the optional extra: pip install 'letspi[ray]'") from exc
    return ray


class RayChunkWorker:
    """The actor class (made remote at run time, so importing this module does not import Ray)."""

    def __init__(self, planner_spec: PlannerSpecLike, config: ClosedLoopConfig) -> None:
        self._worker = ChunkWorker(planner_spec, config)

    def run(self, task: ChunkTask) -> ClosedLoopChunk:
        return self._worker.run(task)

    def pid(self) -> int:
        return os.getpid()


def ensure_ray(address: str, num_cpus: int) -> ModuleType:
    """Ray, initialised: an existing instance as is; "local" starts one with ``num_cpus`` (shut down on Ctrl-C)."""
    ray = import_ray()
    if not ray.is_initialized():
        on_stop(ray.shutdown)  # before init: Ctrl-C during the start also ends what it started
        if address == "local":
            ray.init(num_cpus=num_cpus, include_dashboard=False)
        else:
            ray.init(address=address)
    return ray


def run_on_ray(planner_spec: PlannerSpecLike, tasks: list[ChunkTask], config: ClosedLoopConfig, n_actors: int,
               address: str, max_restarts: int = 2) -> Iterator[ClosedLoopChunk]:
    """Simulate ``tasks`` on ``n_actors`` Ray actors; yield chunks as they complete."""
    ray = ensure_ray(address, n_actors)
    actor_cls = ray.remote(num_cpus=1, max_restarts=max_restarts, max_task_retries=max_restarts)(RayChunkWorker)
    actors = [actor_cls.remote(planner_spec, config) for _ in range(min(n_actors, len(tasks)))]
    pending: deque[ChunkTask] = deque(tasks)
    inflight: dict[Any, tuple[Any, ChunkTask]] = {}

    def submit(actor: Any) -> None:
        if pending:
            task = pending.popleft()
            inflight[actor.run.remote(task)] = (actor, task)

    try:
        for actor in actors:
            submit(actor)
        while inflight:
            done, _ = ray.wait(list(inflight), num_returns=1)
            actor, task = inflight.pop(done[0])
            try:
                result = ray.get(done[0])
            except Exception as exc:  # RayTaskError (exception in the worker) or RayActorError (died)
                raise ClosedLoopWorkerError(f"closed-loop chunk {task.task_id} failed on Ray: {exc}") from exc
            yield result
            submit(actor)
    finally:
        if received() is None:  # after a stop signal the command shuts Ray down (``ensure_ray``), quietly
            for actor in actors:
                ray.kill(actor)
