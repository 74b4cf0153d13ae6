"""The LLM planners' safety shield: unsafe replies are replaced, safe ones kept, --no-shield is raw, keys differ."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from letspi.assembly.build import Builder
from letspi.assembly.planners import build_planner, resolve_planner
from letspi.llm.backends.scripted import ScriptedBackend
from letspi.llm.client import ParamAdvisor
from letspi.method.memory import MemoryBank
from letspi.method.phases import FastPhase, MemoryPhase, Retriever, collect
from letspi.method.reflection import safety_report
from letspi.method.thresholds import ReflectionThresholds
from letspi.metrics.compute import compute_metrics
from letspi.physics.goals import KinematicGoalPredictor
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.params import SocialForceParams
from letspi.planners.base import PlanBatch
from letspi.planners.llm import GRID_SOURCE, IDM_SOURCE, SF_SOURCE, LetsPiFastPlanner, LetsPiMemoryPlanner
from letspi.planners.options import PlannerOptions
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import ScenarioBatch

SAFE_SF = SocialForceParams(k_np=55.0, tau_s=2.5, r_col_m=10.0)  # keeps its distance in _leader()


def _reply(k_np: float, lon: float, tau: float = 1.0) -> str:
    return json.dumps({"why": "x", "tau": tau, "k_np": k_np, "k_nf": 3, "k_nl": 0.5, "k_bd": 1.0, "k_cl": 0.5,
                       "lon": lon, "lane": 0})


def _leader() -> ScenarioBatch:
    # ego 33 m/s, a 20 m/s leader 40 m ahead: weak repulsion and a far goal drive into it
    return straight_road_scenario(ego_speed_mps=33.0, neighbours=[VehicleSpec(x0_m=40.0, speed_mps=20.0)],
                                  scenario_id="leader")


def _fast(reply: str, shield: SocialForceParams | None, retriever: Retriever | None = None) -> LetsPiFastPlanner:
    advisor = ParamAdvisor(ScriptedBackend(default=reply), cache=None, sleep=lambda s: None)
    return LetsPiFastPlanner(FastPhase(advisor, KinematicGoalPredictor(), 10.0, retriever), shield_params=shield)


def _passes(batch: ScenarioBatch, xy: np.ndarray, vxy: np.ndarray) -> bool:
    pred = predict_neighbours(batch.history(), NeighbourPredictionMode.IDM)
    return safety_report(batch.history(), xy, vxy, pred, ReflectionThresholds())[0].safe


def test_a_reply_that_drives_into_the_leader_is_shielded_and_the_plan_passes() -> None:
    batch = _leader()
    raw = _fast(_reply(2.0, 0.0), None).plan(batch.history())
    assert not _passes(batch, raw.xy_m, raw.vxy_mps)
    assert compute_metrics(batch, raw.xy_m, raw.vxy_mps).collision[0]  # the raw plan really crashes

    plan = _fast(_reply(2.0, 0.0), SAFE_SF).plan(batch.history())
    assert plan.info["shielded"][0] == 1.0 and plan.info["shield_safe"][0] == 1.0
    assert plan.info["shield_source"][0] == SF_SOURCE
    assert _passes(batch, plan.xy_m, plan.vxy_mps)
    assert not compute_metrics(batch, plan.xy_m, plan.vxy_mps).collision[0]
    assert plan.info["k_np"][0] == 2.0  # the info still records what the LLM proposed


def test_when_the_fitted_parameters_fail_too_the_grid_around_them_is_tried() -> None:
    weak = SocialForceParams(k_np=10.0, tau_s=1.0, r_col_m=5.0)
    plan = _fast(_reply(2.0, 0.0), weak).plan(_leader().history())
    assert plan.info["shielded"][0] == 1.0 and plan.info["shield_source"][0] == GRID_SOURCE
    assert _passes(_leader(), plan.xy_m, plan.vxy_mps)


def test_a_safe_reply_is_not_shielded_and_no_shield_returns_the_raw_plan() -> None:
    batch = _leader()
    safe_reply = _reply(55.0, 0.8, tau=2.5)
    shielded = _fast(safe_reply, SAFE_SF).plan(batch.history())
    raw = _fast(safe_reply, None).plan(batch.history())
    assert shielded.info["shielded"][0] == 0.0 and shielded.info["shield_checked"][0] == 1.0
    np.testing.assert_array_equal(shielded.xy_m, raw.xy_m)
    assert raw.info["shield_checked"][0] == 0.0


def test_retrieved_memories_come_before_the_fitted_parameters(tmp_path: Path) -> None:
    with MemoryBank.open(tmp_path / "m.sqlite") as bank:
        phase = MemoryPhase(ParamAdvisor(ScriptedBackend(default=_reply(45.0, 0.8, tau=2.5)), cache=None,
                                         sleep=lambda s: None), KinematicGoalPredictor(), r_col_m=10.0,
                            config_key="t")
        assert collect(phase, _leader(), bank).validated == 1
        planner = _fast(_reply(2.0, 0.0), SAFE_SF, Retriever(bank, k=1, allow_same_vehicle=True))
        plan = planner.plan(_leader().history())
    assert plan.info["shielded"][0] == 1.0 and plan.info["shield_source"][0] == 1.0  # memory 1
    assert _passes(_leader(), plan.xy_m, plan.vxy_mps)


def test_memory_planner_shield_replaces_an_unvalidated_single_shot() -> None:
    def planner(shield: SocialForceParams | None) -> LetsPiMemoryPlanner:
        advisor = ParamAdvisor(ScriptedBackend(default=_reply(2.0, 0.0)), cache=None, sleep=lambda s: None)
        phase = MemoryPhase(advisor, KinematicGoalPredictor(), r_col_m=10.0, config_key="t",
                            thresholds=ReflectionThresholds(max_iterations=0))
        return LetsPiMemoryPlanner(phase, name="llm", shield_params=shield)

    raw = planner(None).plan(_leader().history())
    plan = planner(SAFE_SF).plan(_leader().history())
    assert raw.info["validated"][0] == 0.0 and raw.info["shielded"][0] == 0.0
    assert plan.info["shielded"][0] == 1.0 and _passes(_leader(), plan.xy_m, plan.vxy_mps)
    assert plan.info["validated"][0] == 0.0  # the LLM's own answer was not validated: stays recorded


def test_the_shield_is_part_of_the_planner_key_and_the_builder_honours_it() -> None:
    opts = PlannerOptions(llm="scripted:default", fast_llm="scripted:default", llm_cache=False, goals="kinematic")
    for kind in ("llm", "letspi-memory"):
        on, off = resolve_planner(kind, opts), resolve_planner(kind, opts.replace(shield=False))
        assert on.shield and not off.shield and on.key() != off.key()
        # the stored experiences do not depend on the shield
        assert on.phase.key() == off.phase.key()  # type: ignore[union-attr]
    built_on = build_planner(resolve_planner("llm", opts), builder=Builder(cache=None)).planner
    built_off = build_planner(resolve_planner("llm", opts.replace(shield=False)), builder=Builder(cache=None)).planner
    assert built_on.shield_params is not None and built_off.shield_params is None  # type: ignore[attr-defined]


def test_the_idm_fallback_stops_behind_a_stopped_queue_that_every_sf_alternative_runs_into() -> None:
    """A queue stopped 40 m ahead of an ego at 15 m/s (highway-env's densest suite ends so): every preset and sf
    alternative brakes too late, so the shield keeps the plan; ``--idm-fallback`` takes the IDM plan, which stops
    behind the queue. Off by default, and then out of the planner's key."""
    batch = straight_road_scenario(ego_speed_mps=15.0, neighbours=[VehicleSpec(x0_m=40.0, speed_mps=0.0)],
                                   scenario_id="queue")
    options = PlannerOptions(goals="kinematic", gate=False)

    def plan(fallback: bool) -> PlanBatch:
        spec = resolve_planner("sf-check", options.replace(idm_fallback=fallback))
        return build_planner(spec, "sf-check", builder=Builder(cache=None)).planner.plan(batch.history())

    without, with_idm = plan(False), plan(True)
    assert without.info["shield_safe"][0] == 0.0 and without.info["shield_source"][0] != IDM_SOURCE
    assert compute_metrics(batch, without.xy_m, without.vxy_mps).collision[0]
    assert with_idm.info["shielded"][0] == 1.0 and with_idm.info["shield_source"][0] == IDM_SOURCE
    assert not compute_metrics(batch, with_idm.xy_m, with_idm.vxy_mps).collision[0]
    assert with_idm.xy_m[0, -1, 0] < 40.0 - 5.0  # the ego's centre stops a car length behind the queue's
    assert np.all(np.diff(with_idm.xy_m[0, :, 0]) >= -1e-9)  # it brakes, never reverses

    default = resolve_planner("sf-check", options)
    assert resolve_planner("sf-check", options.replace(idm_fallback=False)).key() == default.key()
    assert resolve_planner("sf-check", options.replace(idm_fallback=True)).key() != default.key()
