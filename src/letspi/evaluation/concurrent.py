"""LLM planners in the harness: proposals made N at a time (``letspi.execution.ordered``; context batched per block
of ``CONTEXT_BLOCK`` positions), physics and metrics batched per part (``PART_SCENARIOS`` rows, or after
``PART_FLUSH_S``), parts written in scenario order. ``inference_s``: the scenario's own proposal time (server
queueing included) plus its share of the batched context and physics."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TypeGuard

import numpy as np

from letspi.execution.ordered import BlockCache, RunnerConfig, RunStats, RunStatus, run_ordered
from letspi.llm.client import ParamAdvisor
from letspi.llm.spec import default_concurrency
from letspi.metrics.compute import ScenarioMetrics
from letspi.planners.base import ModelPlanner, PlanBatch, Planner, PlanningContext, Proposals, ProposingPlanner
from letspi.scenario.types import ScenarioBatch

PART_SCENARIOS = 64
PART_FLUSH_S = 5.0
#: dataset positions whose contexts (goals, predicted neighbours) are computed in one batch
CONTEXT_BLOCK = 64

#: (k scenarios with their future, their plans) -> their metrics
Measure = Callable[[ScenarioBatch, PlanBatch], ScenarioMetrics]
#: (metrics of k scenarios, their indices, their plans stacked, their planning times [s]) -> one part written
WritePart = Callable[[ScenarioMetrics, np.ndarray, PlanBatch, np.ndarray], object]


def runs_per_scenario(planner: Planner) -> TypeGuard[ProposingPlanner]:
    """Whether the harness runs ``planner`` through this module (proposals per scenario, concurrently)."""
    return isinstance(planner, ModelPlanner) and planner.proposes_per_scenario and planner.concurrent_safe


def planner_advisor(planner: Planner) -> ParamAdvisor | None:
    advisor = planner.advisor if isinstance(planner, ModelPlanner) else None
    return advisor if isinstance(advisor, ParamAdvisor) else None


def planner_concurrency(planner: Planner, requested: int | None) -> int:
    """``requested``, or the default of the planner's LLM backend (``letspi.llm.spec.default_concurrency``)."""
    if requested is not None:
        return requested
    advisor = planner_advisor(planner)
    return default_concurrency(advisor.backend.spec) if advisor is not None else 1


@dataclass
class _Proposed:
    index: int
    context: PlanningContext
    proposals: Proposals
    seconds: float  # proposal time + share of the block's context time


class _Parts:
    """The writer's side: proposals pooled in scenario order, simulated, scored and written per part."""

    def __init__(self, planner: ProposingPlanner, batch: ScenarioBatch, seen: ScenarioBatch, measure: Measure,
                 write_part: WritePart, contexts: BlockCache[PlanningContext]) -> None:
        self.planner, self.batch, self.seen = planner, batch, seen
        self.measure, self.write_part, self.contexts = measure, write_part, contexts
        self.rows: list[_Proposed] = []
        self.last_flush = time.perf_counter()
        self.physics_cpu_s = 0.0  # simulate + metrics, in this thread

    def add(self, proposed: _Proposed) -> None:
        self.rows.append(proposed)
        if len(self.rows) >= PART_SCENARIOS or time.perf_counter() - self.last_flush >= PART_FLUSH_S:
            self.flush()

    def flush(self) -> None:
        rows = self.rows
        if rows:
            idx = np.array([r.index for r in rows])
            t0, c0 = time.perf_counter(), time.thread_time()
            plan = self.planner.simulate(self.seen.take(idx), PlanningContext.concat([r.context for r in rows]),
                                         Proposals.concat([r.proposals for r in rows]))
            share = (time.perf_counter() - t0) / len(rows)
            metrics = self.measure(self.batch.take(idx), plan)
            self.physics_cpu_s += time.thread_time() - c0
            self.write_part(metrics, idx, plan, np.array([r.seconds + share for r in rows]))
            self.contexts.discard_below(int(idx[-1]) + 1)
        self.rows, self.last_flush = [], time.perf_counter()


def plan_concurrently(
    planner: ProposingPlanner,
    batch: ScenarioBatch,
    todo: Sequence[int],
    *,
    reads_future: bool = False,
    measure: Measure,
    write_part: WritePart,
    runner: RunnerConfig,
    progress: Callable[[int, RunStatus | None], None] | None = None,
) -> RunStats:
    """Propose for ``todo`` (indices into ``batch``) ``runner.concurrency`` at a time; simulate, score and write per
    part in scenario order, here. Raises what ``run_ordered`` raises, after writing every row it accepted."""
    seen_all = batch if reads_future else batch.history()
    contexts: BlockCache[PlanningContext] = BlockCache(CONTEXT_BLOCK, len(batch),
                                                       lambda rows: planner.context(seen_all.take(rows)))
    parts = _Parts(planner, batch, seen_all, measure, write_part, contexts)

    def work(i: int) -> _Proposed:
        block, offset, context_s = contexts.get(i)
        own = block.take([offset])
        t0 = time.perf_counter()
        proposals = planner.propose(seen_all.take([i]), own)
        return _Proposed(i, own, proposals, time.perf_counter() - t0 + context_s)

    reported = 0

    def on_status(status: RunStatus) -> None:
        nonlocal reported
        if progress is not None:
            progress(status.done - reported, status)
            reported = status.done

    def is_fallback(proposed: _Proposed) -> bool:
        return bool(np.asarray(proposed.proposals.info.get("fallback", [False]))[0])

    try:
        stats = run_ordered(todo, work, lambda i, proposed: parts.add(proposed), config=runner,
                            advisor=planner_advisor(planner), is_fallback=is_fallback, progress=on_status)
    finally:
        parts.flush()
    return replace(stats, physics_cpu_s=parts.physics_cpu_s + contexts.cpu_s)
