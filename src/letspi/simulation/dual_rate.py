"""Dual-rate LetsPi in the closed loop: the engine's replanning step for LLM planners.

``DualRateReplanner`` is a ``letspi.simulation.replan.Replanner``. At t = 0 and every ``replan_every``
frames (e.g. 0.2 s) it builds the planner's view from the simulated history, derives the context
(goal prediction, neighbour prediction) and asks the ``DualRateSchedule``
(``letspi.planners.dual_rate``) for the proposals in force, which makes the LLM calls that are due
(t = 0, then every ``llm_period_s``) and applies the answers whose latency has passed. The physics
(``planner.simulate``: rollout and, when on, the safety shield) then plans every scenario of the
group with those proposals, in one batched call.

Recorded per scenario and replan (``Replan.info``): the planner's own info of the plan, overridden
by the schedule's (``llm_calls`` etc. count the calls *made* at this replan, not the proposal in
force), ``llm_in_force``, ``params_age_s``, ``llm_answer_latency_s`` and ``planner_cpu_ms`` (CPU time
of this thread in context and physics per scenario; the LLM calls are not in it).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from letspi.constants import N_FUTURE, N_TOTAL, T0_INDEX
from letspi.planners.dual_rate import DualRateConfig, DualRatePlanner, DualRateSchedule
from letspi.scenario.types import ScenarioBatch
from letspi.simulation.replan import FuturePolicy, Replan, SimulatedStates, replan_frames_of, replanning_batch


class DualRateReplanner:
    """LLM at the schedule's instants, physics every ``replan_every`` frames (module docstring).

    ``concurrency``: LLM calls in flight at once (the K scenarios' calls of one instant).
    ``close()`` drops calls still outstanding (the engine's caller calls it).
    """

    def __init__(self, planner: DualRatePlanner, batch: ScenarioBatch, replan_every: int, future: FuturePolicy,
                 config: DualRateConfig, *, concurrency: int = 1,
                 clock: Callable[[], float] = time.perf_counter) -> None:
        self.planner = planner
        self.batch = batch
        self.replan_every = int(replan_every)
        self.future: FuturePolicy = future
        self.schedule = DualRateSchedule(planner, len(batch), config, concurrency, clock)
        self._frames = replan_frames_of(self.replan_every)
        self._due = set(self._frames)

    @property
    def frames(self) -> list[int]:
        return self._frames

    def plans(self, frame: int, states: SimulatedStates) -> Replan | None:
        if frame not in self._due:
            return None
        k = len(self.batch)
        t0 = time.perf_counter()
        view, centre = replanning_batch(self.batch, states, frame, self.future)
        cpu0 = time.thread_time()
        context = self.planner.context(view)
        cpu_context = time.thread_time() - cpu0
        proposals, schedule_info = self.schedule.step(frame - T0_INDEX, view, context)
        if frame == self._frames[-1]:
            self.schedule.finish(schedule_info)
        cpu1 = time.thread_time()
        plan = self.planner.simulate(view, context, proposals)
        cpu_physics = cpu_context + time.thread_time() - cpu1
        plan_s = time.perf_counter() - t0
        if plan.xy_m.shape != (k, N_FUTURE, 2):
            raise ValueError(f"planner {self.planner.name!r} returned plans of shape {plan.xy_m.shape}, "
                             f"expected {(k, N_FUTURE, 2)}")
        info = {key: np.asarray(val) for key, val in plan.info.items()}
        info = {key: arr for key, arr in info.items() if arr.ndim == 1 and arr.dtype.kind in "biuf"}
        info.update(schedule_info)
        info["planner_cpu_ms"] = np.full(k, 1e3 * cpu_physics / max(k, 1))
        return Replan(
            rows=np.arange(k),
            xy_m=np.asarray(plan.xy_m, dtype=np.float64) + centre[:, None, :],
            vxy_mps=np.asarray(plan.vxy_mps, dtype=np.float64),
            goals_xy_m=np.asarray(plan.goals_xy_m, dtype=np.float64) + centre,
            follow_until=np.full(k, min(frame + self.replan_every, N_TOTAL - 1), dtype=np.int64),
            info=info,
            plan_s=plan_s,
        )

    def close(self) -> None:
        self.schedule.close()
