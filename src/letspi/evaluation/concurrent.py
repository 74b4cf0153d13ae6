"""Per-scenario planners (the LLM planners) in the harness: N scenarios in flight, parts in scenario order.

A planner that plans one scenario per call and says its ``plan`` is thread-safe (``concurrent_safe``)
runs through ``letspi.core.runner``: each scenario is one task (plan on the history-only view unless
the planner reads the future, then score it against the full scenario), and the calling thread
collects the scored rows in scenario order and writes them as part files of up to
``PART_SCENARIOS`` rows, or sooner when ``PART_FLUSH_S`` passed since the last part (so a killed run
loses at most a few seconds of work). Every row's values are those of its own scenario alone, so
neither the concurrency nor the part boundaries change what is stored; ``inference_s`` is the
scenario's own wall time in its task (with N in flight it includes waiting in the server's queue).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from letspi.core.runner import RunnerConfig, RunStats, RunStatus, run_ordered
from letspi.llm.client import ParamAdvisor
from letspi.llm.spec import default_concurrency
from letspi.planners.base import PlanBatch, Planner
from letspi.scenario.types import ScenarioBatch

PART_SCENARIOS = 64
PART_FLUSH_S = 5.0

#: (rows of one scenario's index, the scenario, its plan, its planning time [s]) -> its scored row
Score = Callable[[np.ndarray, ScenarioBatch, PlanBatch, float], pd.DataFrame]
#: (rows, plan xy, plan vxy, goals) -> one part file written
WritePart = Callable[[pd.DataFrame, np.ndarray, np.ndarray, np.ndarray], object]


def runs_per_scenario(planner: Planner) -> bool:
    """Whether the harness runs ``planner`` through the concurrent per-scenario path."""
    return int(planner.batch_size) == 1 and bool(getattr(planner, "concurrent_safe", False))


def planner_advisor(planner: Planner) -> ParamAdvisor | None:
    advisor = getattr(planner, "advisor", None)
    return advisor if isinstance(advisor, ParamAdvisor) else None


def planner_concurrency(planner: Planner, requested: int | None) -> int:
    """``requested``, or the default of the planner's LLM backend (``letspi.llm.spec.default_concurrency``)."""
    if requested is not None:
        return requested
    advisor = planner_advisor(planner)
    return default_concurrency(advisor.backend.spec) if advisor is not None else 1


@dataclass
class _Scored:
    frame: pd.DataFrame
    plan: PlanBatch


def plan_concurrently(
    planner: Planner,
    batch: ScenarioBatch,
    todo: Sequence[int],
    *,
    score: Score,
    write_part: WritePart,
    runner: RunnerConfig,
    progress: Callable[[int, RunStatus | None], None] | None = None,
) -> RunStats:
    """Plan and score ``todo`` (indices into ``batch``) ``runner.concurrency`` at a time; parts are
    written in scenario order by this thread (module docstring). Raises what ``run_ordered`` raises,
    after writing every row it accepted."""
    rows: list[_Scored] = []
    last_flush = time.perf_counter()

    def flush() -> None:
        nonlocal rows, last_flush
        if rows:
            frame = pd.concat([r.frame for r in rows], ignore_index=True)
            write_part(frame, *(np.concatenate([getattr(r.plan, a) for r in rows])
                                for a in ("xy_m", "vxy_mps", "goals_xy_m")))
        rows, last_flush = [], time.perf_counter()

    def work(i: int) -> _Scored:
        one = batch.take([i])
        seen = one if planner.reads_future else one.history()
        t0 = time.perf_counter()
        plan = planner.plan(seen)
        elapsed = time.perf_counter() - t0
        return _Scored(score(np.array([i], dtype=np.int64), one, plan, elapsed), plan)

    def write(i: int, scored: _Scored) -> None:
        rows.append(scored)
        if len(rows) >= PART_SCENARIOS or time.perf_counter() - last_flush >= PART_FLUSH_S:
            flush()

    reported = 0

    def on_status(status: RunStatus) -> None:
        nonlocal reported
        if progress is not None:
            progress(status.done - reported, status)
            reported = status.done

    def is_fallback(scored: _Scored) -> bool:
        return bool(np.asarray(scored.plan.info.get("fallback", [False]))[0])

    try:
        return run_ordered(todo, work, write, config=runner, advisor=planner_advisor(planner),
                           is_fallback=is_fallback, progress=on_status)
    finally:
        flush()
