"""Dual-rate LetsPi in the closed loop: the engine's replanning step for LLM planners (the schedule makes the LLM
calls due; the physics plans the group every ``replan_every`` frames in one batched call). With ``release`` and a
``ReleasingPlanner``, held presets the scene no longer calls for give way to the defaults first (``released_n``)."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from letspi.constants import T0_INDEX
from letspi.metrics.registry import Metric
from letspi.planners.base import PlanBatch
from letspi.scenario.types import ScenarioBatch
from letspi.simulation.replan import FuturePolicy, PeriodicReplanner
from letspi.simulation.schedule import DualRateConfig, DualRatePlanner, DualRateSchedule, ReleasingPlanner

RELEASED = "released_n"
#: per-scenario columns the dual-rate replanner adds (stored at t = 0 and as the mean over replans)
OUTPUTS: tuple[Metric, ...] = (
    Metric(RELEASED, "n", "float64", "1 when a held preset gave way to the defaults at the replan (release); "
           "its mean over the replans is the share of the scenario's replans that released one", None),)


class DualRateReplanner(PeriodicReplanner):
    """LLM at the schedule's instants (``concurrency`` in flight), physics every ``replan_every`` frames."""

    def __init__(self, planner: DualRatePlanner, batch: ScenarioBatch, replan_every: int, future: FuturePolicy,
                 config: DualRateConfig, *, concurrency: int = 1,
                 clock: Callable[[], float] = time.perf_counter) -> None:
        super().__init__(planner, batch, replan_every, future)
        self.planner: DualRatePlanner = planner
        self.schedule = DualRateSchedule(planner, len(batch), config, concurrency, clock)

    def _plan(self, frame: int, view: ScenarioBatch) -> tuple[PlanBatch, dict[str, np.ndarray]]:
        """The physics on the proposals in force; the schedule's info and ``planner_cpu_ms`` (without LLM calls)."""
        k = len(self.batch)
        cpu0 = time.thread_time()
        context = self.planner.context(view)
        cpu_context = time.thread_time() - cpu0
        proposals, schedule_info = self.schedule.step(frame - T0_INDEX, view, context)
        if frame == self._frames[-1]:
            self.schedule.finish(schedule_info)
        cpu1 = time.thread_time()
        release = self.schedule.config.release
        if release != "off" and isinstance(self.planner, ReleasingPlanner) and self.planner.holds_presets:
            proposals, released = self.planner.release_held(view, context, proposals, release)
            schedule_info[RELEASED] = np.asarray(released, dtype=np.float64)
        plan = self.planner.simulate(view, context, proposals)
        cpu_physics = cpu_context + time.thread_time() - cpu1
        schedule_info["planner_cpu_ms"] = np.full(k, 1e3 * cpu_physics / max(k, 1))
        return plan, schedule_info

    def close(self) -> None:
        self.schedule.close()
