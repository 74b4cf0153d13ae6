"""Worker processes for closed-loop runs: one planner and one libsumo per spawned process, one chunk at a time. A
dead worker's chunk is requeued (``max_restarts`` replacements); workers ignore Ctrl-C and are terminated when a run
ends early."""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import traceback
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from multiprocessing.process import BaseProcess

from letspi.execution.interrupt import run_worker, start_worker
from letspi.simulation.config import ClosedLoopConfig
from letspi.simulation.result import ClosedLoopChunk
from letspi.simulation.spec import PlannerSpecLike
from letspi.simulation.worker import ChunkTask, ChunkWorker

JOIN_TIMEOUT_S = 5.0
#: seconds a terminated worker gets before it is killed (a worker inside libsumo ends at once)
TERMINATE_TIMEOUT_S = 1.0


class ClosedLoopWorkerError(RuntimeError):
    """A worker failed (its traceback is in the message) or died too often."""


def _worker_main(conn: Connection, planner_spec: PlannerSpecLike, config: ClosedLoopConfig) -> None:
    """A worker process: build once, simulate chunks until told to stop; SIGTERM closes SUMO, then exits at once."""
    run_worker(lambda: _serve(conn, planner_spec, config))


def _serve(conn: Connection, planner_spec: PlannerSpecLike, config: ClosedLoopConfig) -> None:
    try:
        worker = ChunkWorker(planner_spec, config)
    except Exception:
        conn.send(("error", -1, traceback.format_exc()))
        return
    try:
        conn.send(("ready", os.getpid(), None))
        while True:
            task = conn.recv()
            if task is None:
                break
            try:
                result = worker.run(task)
            except Exception:
                conn.send(("error", task.task_id, traceback.format_exc()))
                break
            conn.send(("done", task.task_id, result))
    except (EOFError, BrokenPipeError):
        pass
    finally:
        worker.close()


@dataclass
class _Slot:
    process: BaseProcess
    conn: Connection
    task: ChunkTask | None = None
    ready: bool = False


def run_in_processes(planner_spec: PlannerSpecLike, tasks: list[ChunkTask], config: ClosedLoopConfig, workers: int,
                     max_restarts: int = 2) -> Iterator[ClosedLoopChunk]:
    """Simulate ``tasks`` on ``workers`` processes; yield chunks as they complete."""
    ctx = mp.get_context("spawn")
    pending: deque[ChunkTask] = deque(tasks)
    slots: list[_Slot] = []
    restarts = 0

    def start() -> _Slot:
        parent, child = ctx.Pipe(duplex=True)
        proc = ctx.Process(target=_worker_main, args=(child, planner_spec, config), daemon=True,
                           name="letspi-simulation-worker")
        start_worker(proc)  # the terminal's Ctrl-C is the parent's to handle, not the worker's
        child.close()
        return _Slot(proc, parent)

    def feed(slot: _Slot) -> None:
        if slot.ready and slot.task is None and pending:
            slot.task = pending.popleft()
            try:
                slot.conn.send(slot.task)
            except (BrokenPipeError, OSError):
                pass  # it died: its sentinel reports it and the task is requeued

    def replace_dead(slot: _Slot) -> _Slot:
        nonlocal restarts
        restarts += 1
        code = slot.process.exitcode
        if slot.task is not None:
            pending.appendleft(slot.task)
        slot.conn.close()
        if restarts > max_restarts:
            raise ClosedLoopWorkerError(f"a closed-loop worker died (exit code {code}) and the restart budget "
                                        f"({max_restarts}) is used up; rerun to resume")
        return start()

    remaining = len(tasks)
    finished = False
    try:
        slots = [start() for _ in range(min(workers, len(tasks)))]
        while remaining:
            waitables = [s.conn for s in slots] + [s.process.sentinel for s in slots]
            ready = wait(waitables)
            # messages first: a worker may have sent its result just before it died
            for i, slot in enumerate(list(slots)):
                if slot.conn not in ready:
                    continue
                try:
                    kind, ident, payload = slot.conn.recv()
                except (EOFError, OSError):
                    continue  # died; handled through the sentinel below
                if kind == "error":
                    raise ClosedLoopWorkerError(f"closed-loop worker failed (chunk {ident}):\n{payload}")
                if kind == "ready":
                    slots[i].ready = True
                elif kind == "done":
                    if slot.task is None or slot.task.task_id != ident:
                        raise ClosedLoopWorkerError(f"worker returned chunk {ident}, expected "
                                                    f"{None if slot.task is None else slot.task.task_id}")
                    slot.task = None
                    remaining -= 1
                    yield payload
                feed(slot)
            for i, slot in enumerate(list(slots)):
                if slot.process.sentinel in ready and not slot.process.is_alive():
                    slot.process.join(0)
                    slots[i] = replace_dead(slot)
            for slot in slots:
                feed(slot)
        finished = True
    finally:
        _shut_down(slots, finished)


def _shut_down(slots: list[_Slot], finished: bool) -> None:
    """A finished run asks its idle workers to exit and waits; one ended early (Ctrl-C, an error, a consumer that
    stopped) terminates them at once, then kills any left."""
    if finished:
        for slot in slots:
            with contextlib.suppress(Exception):
                slot.conn.send(None)
    else:
        for slot in slots:
            with contextlib.suppress(Exception):
                slot.process.terminate()
    for slot in slots:
        slot.process.join(JOIN_TIMEOUT_S if finished else TERMINATE_TIMEOUT_S)
        if slot.process.is_alive():
            if finished:
                slot.process.terminate()
            else:
                slot.process.kill()
            slot.process.join(JOIN_TIMEOUT_S)
        with contextlib.suppress(Exception):
            slot.conn.close()
