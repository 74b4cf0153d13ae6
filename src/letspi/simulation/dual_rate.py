"""Dual-rate LetsPi in the closed loop: the engine's replanning step for LLM planners.

``DualRateReplanner`` is a ``letspi.simulation.replan.Replanner``. At t = 0 and every ``replan_every``
frames (e.g. 0.2 s) it builds the planner's view from the simulated history, derives the context
(goal prediction, neighbour prediction) and asks the ``DualRateSchedule``
(``letspi.simulation.schedule``) for the proposals in force, which makes the LLM calls that are due
(t = 0, then every ``llm_period_s``) and applies the answers whose latency has passed. The physics
(``planner.simulate``: rollout and, when on, the safety shield) then plans every scenario of the
group with those proposals, in one batched call.

With ``release`` (``DualRateConfig``) and a ``ReleasingPlanner``, the held presets the scene observed now
no longer calls for give way to the defaults before the physics plans (``released_n``).

Recorded per scenario and replan (``Replan.info``): the planner's own info of the plan, overridden
by the schedule's (``llm_calls`` etc. count the calls *made* at this replan, not the proposal in
force), ``llm_in_force``, ``params_age_s``, ``llm_answer_latency_s``, ``released_n`` (1: a held preset
gave way to the defaults at this replan) and ``planner_cpu_ms`` (CPU time of this thread in context,
release and physics per scenario; the LLM calls are not in it).
"""

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
#: per-scenario columns the dual-rate replanner adds (each replan's value; the harness stores the first
#: replan's and the mean over replans)
OUTPUTS: tuple[Metric, ...] = (
    Metric(RELEASED, "n", "float64", "1 when a held preset gave way to the defaults at the replan (release); "
           "its mean over the replans is the share of the scenario's replans that released one", None),)


class DualRateReplanner(PeriodicReplanner):
    """LLM at the schedule's instants, physics every ``replan_every`` frames (module docstring).

    ``concurrency``: LLM calls in flight at once (the K scenarios' calls of one instant).
    ``close()`` drops calls still outstanding (the engine's caller calls it).
    """

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
        release = self.schedule.config.release
        if release != "off" and isinstance(self.planner, ReleasingPlanner):
            proposals, released = self.planner.release_held(view, context, proposals, release)
            schedule_info[RELEASED] = np.asarray(released, dtype=np.float64)
        plan = self.planner.simulate(view, context, proposals)
        cpu_physics = cpu_context + time.thread_time() - cpu1
        schedule_info["planner_cpu_ms"] = np.full(k, 1e3 * cpu_physics / max(k, 1))
        return plan, schedule_info

    def close(self) -> None:
        self.schedule.close()
