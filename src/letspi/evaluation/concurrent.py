"""Per-scenario planners (the LLM planners) in the harness: N scenarios in flight, parts in scenario order.

A planner that plans one scenario per call and says its ``plan`` is thread-safe (``concurrent_safe``)
runs through ``letspi.method.runner``: each scenario is one task (plan on the history-only view unless
the planner reads the future, then its metrics against the full scenario), and the calling thread
collects the results in scenario order and writes them as part files of up to ``PART_SCENARIOS``
rows, or sooner when ``PART_FLUSH_S`` passed since the last part (so a killed run loses at most a few
seconds of work; the table is built once per part, not per scenario). Every row's values are those of
its own scenario alone (metrics are computed per scenario), so neither the concurrency nor the part
boundaries change what is stored; ``inference_s`` is the scenario's own wall time in its task (with N
in flight it includes waiting in the server's queue).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from letspi.llm.client import ParamAdvisor
from letspi.llm.spec import default_concurrency
from letspi.method.runner import RunnerConfig, RunStats, RunStatus, run_ordered
from letspi.metrics.compute import ScenarioMetrics
from letspi.planners.base import PlanBatch, Planner
from letspi.scenario.types import ScenarioBatch

PART_SCENARIOS = 64
PART_FLUSH_S = 5.0

#: (one scenario with its future, its plan) -> its metrics
Measure = Callable[[ScenarioBatch, PlanBatch], ScenarioMetrics]
#: (metrics of k scenarios, their indices, their plans stacked, their planning times [s]) -> one part written
WritePart = Callable[[ScenarioMetrics, np.ndarray, PlanBatch, np.ndarray], object]


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
    index: int
    metrics: ScenarioMetrics
    plan: PlanBatch
    seconds: float


def _stack(plans: Sequence[PlanBatch]) -> PlanBatch:
    info = {k: np.concatenate([np.asarray(p.info[k]) for p in plans]) for k in plans[0].info}
    return PlanBatch(xy_m=np.concatenate([p.xy_m for p in plans]), vxy_mps=np.concatenate([p.vxy_mps for p in plans]),
                     goals_xy_m=np.concatenate([p.goals_xy_m for p in plans]), info=info)


def plan_concurrently(
    planner: Planner,
    batch: ScenarioBatch,
    todo: Sequence[int],
    *,
    measure: Measure,
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
            write_part(ScenarioMetrics.concat([r.metrics for r in rows]), np.array([r.index for r in rows]),
                       _stack([r.plan for r in rows]), np.array([r.seconds for r in rows]))
        rows, last_flush = [], time.perf_counter()

    def work(i: int) -> _Scored:
        one = batch.take([i])
        seen = one if planner.reads_future else one.history()
        t0 = time.perf_counter()
        plan = planner.plan(seen)
        elapsed = time.perf_counter() - t0
        return _Scored(i, measure(one, plan), plan, elapsed)

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
