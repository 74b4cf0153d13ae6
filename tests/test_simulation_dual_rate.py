"""Dual-rate LetsPi in the closed-loop engine: the LLM at t = 0 and every period, its answers in force
after their latency, the physics (and the shield) at every replan with the parameters in force.

The LLM is a scripted fake (``ScriptedBackend``): these are tests of the control flow, not of a model.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from benchmarks.speed import app as speed_app
from letspi.assembly.planner_table import BUILT_IN
from letspi.assembly.planners import BuiltPlanner
from letspi.constants import N_TOTAL, T0_INDEX
from letspi.llm.backends.scripted import ScriptedBackend
from letspi.llm.client import ParamAdvisor
from letspi.llm.schema import fallback_reply_from_params
from letspi.method.phases import FastPhase
from letspi.physics.goals import KinematicGoalPredictor
from letspi.physics.params import SocialForceParams
from letspi.planners.config import GoalsConfig
from letspi.planners.llm import FastPlannerConfig, LetsPiFastPlanner
from letspi.planners.sf import SocialForcePlanner
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.store import save_scenarios
from letspi.scenario.types import ScenarioBatch, concat_batches
from letspi.simulation import ClosedLoopChunk, ClosedLoopConfig, run_closed_loop
from letspi.simulation.dual_rate import DualRateReplanner
from letspi.simulation.replan import PeriodicReplanner, Replan, SimulatedStates, replanning_batch
from letspi.simulation.schedule import DualRateConfig, DualRatePlanner

FITTED = SocialForceParams(tau_s=1.7, k_np=33.0, k_nf=4.0, k_nl=0.6, k_boundary=1.1, k_cline=0.4, r_col_m=9.0)


def _reply(k_np: float) -> str:
    return json.dumps({"tau": 1.2, "k_np": k_np, "k_nf": 3, "k_nl": 0.5, "k_bd": 1.0, "k_cl": 0.5, "lon": 0.6,
                       "lane": 0})


def _fast(replies: list[str], default_k_np: float = 44.0, shield: bool = True) -> LetsPiFastPlanner:
    advisor = ParamAdvisor(ScriptedBackend(replies, default=_reply(default_k_np)), cache=None, sleep=lambda s: None,
                           fallback_reply=fallback_reply_from_params(FITTED))
    return LetsPiFastPlanner(FastPhase(advisor, KinematicGoalPredictor(), FITTED.r_col_m, None),
                             shield_params=FITTED if shield else None)


def _calls(planner: LetsPiFastPlanner) -> int:
    return len(planner.phase.advisor.backend.calls)  # type: ignore[attr-defined]


def _scenes(k: int) -> ScenarioBatch:
    return concat_batches([straight_road_scenario(neighbours=[VehicleSpec(x0_m=35.0 + 10 * i, speed_mps=24.0),
                                                              VehicleSpec(x0_m=-25.0, speed_mps=30.0)],
                                                  scenario_id=f"d{i}") for i in range(k)])


def _logged_states(batch: ScenarioBatch) -> SimulatedStates:
    """The recording as if simulated (a replanner only reads the states)."""
    return SimulatedStates(batch.ego_xy_m.astype(np.float64), batch.ego_vxy_mps.astype(np.float64),
                           batch.ego_axy_mps2.astype(np.float64), batch.ego_lane_id, batch.nbr_xy_m.astype(np.float64),
                           batch.nbr_vxy_mps.astype(np.float64), batch.nbr_valid, batch.nbr_lane_id)


def _replans(replanner: DualRateReplanner | PeriodicReplanner, states: SimulatedStates) -> dict[int, Replan]:
    out = {}
    for frame in range(N_TOTAL):
        replan = replanner.plans(frame, states)
        if replan is not None:
            out[frame - T0_INDEX] = replan
    return out


def test_the_llm_is_asked_at_t0_and_every_period_and_the_physics_replans_with_the_answer_in_force() -> None:
    batch = _scenes(2)
    # two scenarios, asked in order at each instant: t = 0 answers k_np 44, t = 2.6 s answers k_np 60
    planner = _fast([_reply(44.0)] * 2 + [_reply(60.0)] * 2)
    assert isinstance(planner, DualRatePlanner) and not isinstance(SocialForcePlanner(FITTED), DualRatePlanner)
    assert BUILT_IN.kind("letspi-fast").dual_rate and not BUILT_IN.kind("sf").dual_rate
    states = _logged_states(batch)
    replanner = DualRateReplanner(planner, batch, 5, "none", DualRateConfig(llm_period_s=2.5, llm_latency_s=1.0))
    out = _replans(replanner, states)
    assert sorted(out) == list(range(0, N_TOTAL - 1 - T0_INDEX, 5))  # physics every 0.2 s
    calls = {s: r.info["llm_calls"].tolist() for s, r in out.items() if r.info["llm_calls"].any()}
    assert calls == {0: [1.0, 1.0], 65: [1.0, 1.0]} and _calls(planner) == 4
    k_np = {s: r.info["k_np"].tolist() for s, r in out.items()}
    assert all(k_np[s] == [FITTED.k_np] * 2 for s in range(0, 25, 5))  # fitted until the answer's 1 s latency
    assert all(k_np[s] == [44.0] * 2 for s in range(25, 90, 5))
    assert all(k_np[s] == [60.0] * 2 for s in range(90, 125, 5))
    np.testing.assert_allclose(out[60].info["params_age_s"], [2.4, 2.4])  # the t = 0 answer, 60 frames old
    np.testing.assert_allclose(out[90].info["params_age_s"], [1.0, 1.0])  # the 2.6 s answer
    assert np.isnan(out[20].info["params_age_s"]).all() and out[20].info["llm_in_force"].tolist() == [0.0, 0.0]
    np.testing.assert_allclose(out[25].info["llm_answer_latency_s"], [1.0, 1.0])
    for r in out.values():  # the shield checks every replan; physics CPU recorded per replan
        assert r.info["shield_checked"].tolist() == [1.0, 1.0]
        assert np.all(np.isfinite(r.info["planner_cpu_ms"])) and np.all(r.info["planner_cpu_ms"] >= 0)
    # at 3 s the plan is the planner's own physics, against the scene of that instant, with the answer in force
    frame = T0_INDEX + 75
    view, centre = replanning_batch(batch, states, frame, "none")
    own = _fast([], default_k_np=44.0).plan(view)
    np.testing.assert_array_equal(out[75].xy_m, own.xy_m + centre[:, None, :])
    # before the first answer: the fitted parameters' plan
    view0, centre0 = replanning_batch(batch, states, T0_INDEX + 10, "none")
    context = planner.context(view0)
    fitted = planner.simulate(view0, context, planner.default_proposals(view0))
    np.testing.assert_array_equal(out[10].xy_m, fitted.xy_m + centre0[:, None, :])


def test_asking_at_every_replan_without_latency_is_the_periodic_replanner_bit_for_bit() -> None:
    batch = _scenes(2)
    states = _logged_states(batch)
    replies = [_reply(30.0 + i) for i in range(60)]  # a different answer at every call
    dual = _replans(DualRateReplanner(_fast(replies), batch, 25, "none",
                                      DualRateConfig(llm_period_s=1.0, llm_latency_s=0.0)), states)
    every = _replans(PeriodicReplanner(_fast(replies), batch, 25, "none"), states)
    assert sorted(dual) == sorted(every) == [0, 25, 50, 75, 100]
    for s in dual:
        np.testing.assert_array_equal(dual[s].xy_m, every[s].xy_m)
        np.testing.assert_array_equal(dual[s].goals_xy_m, every[s].goals_xy_m)
        np.testing.assert_array_equal(dual[s].info["k_np"], every[s].info["k_np"])
        assert dual[s].info["llm_calls"].tolist() == [1.0, 1.0]


def test_a_period_as_long_as_the_horizon_asks_once_and_without_the_shield_nothing_is_checked() -> None:
    batch = _scenes(1)
    planner = _fast([], shield=False)
    out = _replans(DualRateReplanner(planner, batch, 5, "none", DualRateConfig(llm_period_s=5.0, llm_latency_s=0.0)),
                   _logged_states(batch))
    assert sum(float(r.info["llm_calls"][0]) for r in out.values()) == 1.0 and _calls(planner) == 1
    assert all("shield_checked" not in r.info or r.info["shield_checked"][0] == 0.0 for r in out.values())
    np.testing.assert_allclose(out[120].info["params_age_s"], [4.8])


@pytest.mark.sumo
@pytest.mark.parametrize("mode", ["closed-loop-log", "closed-loop-reactive", "closed-loop-hybrid"])
def test_dual_rate_letspi_in_the_engine_asks_twice_per_5_s_scenario_and_records_the_age(mode: str) -> None:
    batch = _scenes(2)
    planner = _fast([])
    config = ClosedLoopConfig(mode=mode, replan_s=0.2, dual_rate=DualRateConfig(llm_period_s=2.5, llm_latency_s=0.4))
    # the planner object as a letspi-fast of the table (its kind runs dual-rate); the configuration is a stand-in
    built = BuiltPlanner("letspi-fast", FastPlannerConfig.model_construct(goals=GoalsConfig(source="kinematic")),
                         planner)
    chunks = list(run_closed_loop(built, batch, config))
    chunk = ClosedLoopChunk.concat(chunks)
    info = chunk.plan_info
    assert chunk.plan_xy_m.shape[1] == 25  # replans at 0, 0.2, ..., 4.8 s
    np.testing.assert_array_equal(np.nansum(info["llm_calls"], axis=1), [2.0, 2.0])
    assert _calls(planner) == 4
    assert np.all(info["shield_checked"][:, :25] == 1.0)
    age = info["params_age_s"]
    assert np.isnan(age[:, :2]).all() and np.allclose(age[:, 2], 0.4) and np.nanmax(age) <= 2.6 + 0.4 + 1e-9
    assert np.all(np.isfinite(info["planner_cpu_ms"][:, :25]))
    assert not chunk.plan_nonfinite.any()


@pytest.mark.sumo
def test_bench_closed_loop_of_an_llm_planner_reports_real_time_calls_and_the_first_answer(tmp_path: Path) -> None:
    scenarios = save_scenarios(_scenes(3), tmp_path / "s.arrow")
    result = CliRunner().invoke(speed_app, ["closed-loop", "--planner", "llm", "--llm", "scripted:default",
                                      "--scenarios", str(scenarios), "--n", "2", "--replan-s", "0.2",
                                      "--llm-latency-s", "0.4", "--json"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    assert out["llm_calls_per_scenario"] == 2.0 and out["n_scenarios"] == 2.0
    assert out["first_answer_in_force_s_mean"] == pytest.approx(0.4)
    assert out["llm_in_force_pct"] == pytest.approx(100.0 * 23 / 25)
    assert out["llm_answer_latency_s_mean"] == pytest.approx(0.4)
    assert 0 < out["wall_s_per_scenario_mean"] <= out["wall_s_per_scenario_max"]
    assert out["planner_cpu_ms_per_scenario_per_replan"] > 0
    code = CliRunner().invoke(speed_app, ["closed-loop", "--planner", "llm", "--llm", "scripted:default",
                                    "--scenarios", str(scenarios), "--n", "1", "--llm-period-s", "-1"])
    assert code.exit_code == 2 and "--llm-period-s must be a positive number" in code.output
