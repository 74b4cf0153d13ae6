"""Dual-rate LetsPi in the closed loop: the engine's replanning step for LLM planners (the schedule makes the LLM
calls due; the physics plans the group every ``replan_every`` frames in one batched call)."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from letspi.constants import T0_INDEX
from letspi.planners.base import PlanBatch
from letspi.scenario.types import ScenarioBatch
from letspi.simulation.replan import FuturePolicy, PeriodicReplanner
from letspi.simulation.schedule import DualRateConfig, DualRatePlanner, DualRateSchedule


class DualRateReplanner(PeriodicReplanner):
    """LLM at the schedule's instants, physics every ``replan_every`` frames. ``concurrency``: LLM calls in
    flight at once; ``close()`` drops calls still outstanding."""

    def __init__(self, planner: DualRatePlanner, batch: ScenarioBatch, replan_every: int, future: FuturePolicy,
                 config: DualRateConfig, *, concurrency: int = 1,
                 clock: Callable[[], float] = time.perf_counter) -> None:
        super().__init__(planner, batch, replan_every, future)
        self.planner: DualRatePlanner = planner
        self.schedule = DualRateSchedule(planner, len(batch), config, concurrency, clock)

    def _plan(self, frame: int, view: ScenarioBatch) -> tuple[PlanBatch, dict[str, np.ndarray]]:
        """Context, the proposals in force (the schedule makes the LLM calls due) and the physics; the
        schedule's info and ``planner_cpu_ms`` (context and physics; the LLM calls are not in it)."""
        k = len(self.batch)
        cpu0 = time.thread_time()
        context = self.planner.context(view)
        cpu_context = time.thread_time() - cpu0
        proposals, schedule_info = self.schedule.step(frame - T0_INDEX, view, context)
        if frame == self._frames[-1]:
            self.schedule.finish(schedule_info)
        cpu1 = time.thread_time()
        plan = self.planner.simulate(view, context, proposals)
        cpu_physics = cpu_context + time.thread_time() - cpu1
        schedule_info["planner_cpu_ms"] = np.full(k, 1e3 * cpu_physics / max(k, 1))
        return plan, schedule_info

    def close(self) -> None:
        self.schedule.close()
