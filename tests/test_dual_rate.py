"""Dual-rate LetsPi's schedule: when LLM answers are asked for, when they take effect, what is in force."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field

import numpy as np
import pytest

from letspi.llm.backends.scripted import ScriptedBackend
from letspi.llm.client import ParamAdvisor
from letspi.llm.schema import fallback_reply_from_params
from letspi.method.phases import FastPhase
from letspi.physics.goals import KinematicGoalPredictor
from letspi.physics.neighbours import predict_neighbours
from letspi.physics.params import SocialForceParams
from letspi.planners.base import PlanningContext, Proposals
from letspi.planners.llm import LetsPiFastPlanner
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import ScenarioBatch, concat_batches
from letspi.simulation.schedule import DualRateConfig, DualRateSchedule

FITTED = SocialForceParams(tau_s=1.7, k_np=33.0, k_nf=4.0, k_nl=0.6, k_boundary=1.1, k_cline=0.4, r_col_m=9.0)


def _scenes(k: int) -> ScenarioBatch:
    return concat_batches([straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(x0_m=40.0 + 5 * i,
                                                                                              speed_mps=25.0)],
                                                  scenario_id=f"d{i}") for i in range(k)]).history()


def _fast(k_np: float = 44.0) -> LetsPiFastPlanner:
    reply = json.dumps({"tau": 1.2, "k_np": k_np, "k_nf": 3, "k_nl": 0.5, "k_bd": 1.0, "k_cl": 0.5, "lon": 0.6,
                        "lane": 0})
    advisor = ParamAdvisor(ScriptedBackend(default=reply), cache=None, sleep=lambda s: None,
                           fallback_reply=fallback_reply_from_params(FITTED))
    return LetsPiFastPlanner(FastPhase(advisor, KinematicGoalPredictor(), FITTED.r_col_m, None), shield_params=FITTED)


def _run(schedule: DualRateSchedule, planner: LetsPiFastPlanner, view: ScenarioBatch, steps: range
         ) -> list[tuple[int, Proposals, dict[str, np.ndarray]]]:
    context = planner.context(view)
    return [(s, *schedule.step(s, view, context)) for s in steps]


def test_fixed_latency_answers_take_effect_that_much_later_and_the_fitted_parameters_rule_before() -> None:
    planner, view = _fast(), _scenes(2)
    schedule = DualRateSchedule(planner, 2, DualRateConfig(llm_period_s=1.0, llm_latency_s=0.4))
    out = {s: (p, info) for s, p, info in _run(schedule, planner, view, range(0, 125, 5))}
    # t = 0: the call is made (counted) but its answer is not in force yet: the fitted parameters plan
    p0, i0 = out[0]
    assert i0["llm_calls"].tolist() == [1.0, 1.0] and i0["llm_in_force"].tolist() == [0.0, 0.0]
    assert np.isnan(i0["params_age_s"]).all()
    np.testing.assert_array_equal(p0.params.k_np, [FITTED.k_np] * 2)
    np.testing.assert_array_equal(p0.lon_factor, [0.4] * 2)  # neutral goal
    # 0.4 s = 10 frames later it is
    p10, i10 = out[10]
    np.testing.assert_array_equal(p10.params.k_np, [44.0, 44.0])
    np.testing.assert_allclose(i10["params_age_s"], [0.4, 0.4])
    np.testing.assert_allclose(i10["llm_answer_latency_s"], [0.4, 0.4])
    assert i10["llm_calls"].tolist() == [0.0, 0.0]
    # the age grows until the next answer (asked at 1.0 s) takes over at 1.4 s
    np.testing.assert_allclose(out[30][1]["params_age_s"], [1.2, 1.2])
    np.testing.assert_allclose(out[35][1]["params_age_s"], [0.4, 0.4])
    calls = sum(info["llm_calls"] for _, info in out.values())
    assert calls.tolist() == [5.0, 5.0]  # t = 0, 1, 2, 3, 4 s
    assert len(planner.phase.advisor.backend.calls) == 10  # type: ignore[attr-defined]


def test_zero_latency_puts_the_first_answer_in_force_at_once_and_a_long_period_asks_once() -> None:
    planner, view = _fast(), _scenes(1)
    schedule = DualRateSchedule(planner, 1, DualRateConfig(llm_period_s=5.0, llm_latency_s=0.0))
    out = _run(schedule, planner, view, range(0, 125, 5))
    assert out[0][1].params.k_np.tolist() == [44.0] and out[0][2]["params_age_s"].tolist() == [0.0]
    assert sum(float(info["llm_calls"][0]) for _, _, info in out) == 1.0
    np.testing.assert_allclose(out[-1][2]["params_age_s"], [4.8])


def test_the_in_force_proposals_plan_like_the_planner_itself() -> None:
    """With zero latency at t = 0 the dual-rate plan equals the planner's own plan (same LLM answer)."""
    planner, view = _fast(), _scenes(2)
    schedule = DualRateSchedule(planner, 2, DualRateConfig(llm_latency_s=0.0))
    context = planner.context(view)
    proposals, _ = schedule.step(0, view, context)
    dual = planner.simulate(view, context, proposals)
    own = planner.plan(view)
    np.testing.assert_array_equal(dual.xy_m, own.xy_m)


@dataclass
class _SlowPlanner:
    """Answers k_np = 50 after ``delay_s`` of wall time; the fitted default has k_np = 20."""

    delay_s: float
    name: str = "slow"
    batch_size: int = 64
    reads_future: bool = False
    proposes_per_scenario: bool = True
    calls: list[float] = field(default_factory=list)

    def _proposals(self, n: int, k_np: float) -> Proposals:
        return Proposals(SocialForceParams(k_np=k_np).broadcast(n), np.full(n, 0.4), np.zeros(n),
                         {"llm_calls": np.full(n, 1.0 if k_np == 50.0 else 0.0)})

    def context(self, batch: ScenarioBatch) -> PlanningContext:
        raise NotImplementedError

    def propose(self, batch: ScenarioBatch, context: PlanningContext) -> Proposals:
        self.calls.append(time.perf_counter())
        time.sleep(self.delay_s)
        return self._proposals(len(batch), 50.0)

    def default_proposals(self, batch: ScenarioBatch) -> Proposals:
        return self._proposals(len(batch), 20.0)

    def simulate(self, batch: ScenarioBatch, context: PlanningContext, proposals: Proposals) -> object:
        raise NotImplementedError

    def plan(self, batch: ScenarioBatch) -> object:
        raise NotImplementedError


@pytest.mark.parametrize("delay_s, applied_at", [(0.05, 5), (0.3, 10)])
def test_measured_latency_applies_an_answer_at_the_first_replan_after_it_arrived(delay_s: float,
                                                                                 applied_at: int) -> None:
    """The call runs beside the simulation; simulated time is paced to the wall clock while it is out."""
    planner = _SlowPlanner(delay_s)
    view = _scenes(1)
    dummy = PlanningContext(np.zeros((1, 2)), predict_neighbours(view, "idm"))
    schedule = DualRateSchedule(planner, 1, DualRateConfig(llm_period_s=5.0))  # type: ignore[arg-type]
    t0 = time.perf_counter()
    k_np = {}
    for s in range(0, 30, 5):
        proposals, info = schedule.step(s, view, dummy)
        k_np[s] = float(proposals.params.k_np[0])
        if s == applied_at:
            assert delay_s <= info["llm_answer_latency_s"][0] <= s * 0.04 + 1e-6
            elapsed = time.perf_counter() - t0
    schedule.close()
    assert all(k_np[s] == (50.0 if s >= applied_at else 20.0) for s in k_np), k_np
    assert elapsed >= delay_s  # it waited for the answer (paced), it did not run ahead of it


def test_a_period_of_2_5_s_with_0_2_s_replans_asks_twice_per_5_s_scenario() -> None:
    """Calls at the first replan at or after each multiple of the period: t = 0 and t = 2.6 s."""
    planner, view = _fast(), _scenes(1)
    schedule = DualRateSchedule(planner, 1, DualRateConfig(llm_period_s=2.5, llm_latency_s=1.0))
    out = _run(schedule, planner, view, range(0, 125, 5))
    asked = [s for s, _, info in out if info["llm_calls"][0] > 0]
    assert asked == [0, 65]
    applied = [s for s, _, info in out if np.isfinite(info["llm_answer_latency_s"][0])]
    assert applied == [25, 90]  # 1.0 s = 25 frames later
