"""The two LetsPi phases end to end with a scripted LLM (control flow; real models: test_llm_embedded)."""

from __future__ import annotations

import json

import numpy as np

from letspi.llm.backends.scripted import ScriptedBackend
from letspi.llm.client import ParamAdvisor
from letspi.method.memory import MemoryBank
from letspi.method.phases import FastPhase, MemoryPhase, Retriever, collect
from letspi.method.thresholds import ReflectionThresholds
from letspi.metrics.compute import compute_metrics
from letspi.physics.goals import KinematicGoalPredictor
from letspi.planners.llm import LetsPiFastPlanner, LetsPiMemoryPlanner
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import concat_batches


def _reply(k_np: float, lon: float, why: str = "x", tau: float = 1.0) -> str:
    return json.dumps({"why": why, "tau": tau, "k_np": k_np, "k_nf": 3, "k_nl": 0.5, "k_bd": 1.0, "k_cl": 0.5,
                       "lon": lon, "lane": 0})


def _unsafe():
    # ego 33 m/s, a 20 m/s leader 40 m ahead: weak repulsion drives into it
    return straight_road_scenario(ego_speed_mps=33.0, neighbours=[VehicleSpec(x0_m=40.0, speed_mps=20.0)],
                                  scenario_id="unsafe")


def _advisor(backend: ScriptedBackend) -> ParamAdvisor:
    return ParamAdvisor(backend, cache=None, sleep=lambda s: None)


def _phase(backend: ScriptedBackend, max_iterations: int = 3, key: str = "test") -> MemoryPhase:
    return MemoryPhase(_advisor(backend), KinematicGoalPredictor(), r_col_m=10.0, config_key=key,
                       thresholds=ReflectionThresholds(max_iterations=max_iterations))


def test_memory_phase_reflects_until_safe_and_the_refinement_prompt_carries_the_report():
    backend = ScriptedBackend([_reply(2.0, 0.4, "first"), _reply(55.0, 0.6, "refined", tau=2.5)])
    planner = LetsPiMemoryPlanner(_phase(backend))
    batch = _unsafe()
    plan = planner.plan(batch)
    assert len(planner.last_iterations) == 2 and not planner.last_iterations[0].safe
    assert planner.last_iterations[1].safe and plan.info["validated"][0] == 1.0
    refinement_turn = backend.calls[1][-1]["content"]
    assert "TTC" in refinement_turn or "contact" in refinement_turn.lower()
    assert backend.calls[1][-2]["role"] == "assistant"  # the model's first answer precedes the report
    m = compute_metrics(batch, plan.xy_m, plan.vxy_mps, plan.goals_xy_m)
    assert not m.collision[0]


def test_single_shot_is_reflection_with_zero_refinements():
    backend = ScriptedBackend([_reply(2.0, 0.4)])
    plan = LetsPiMemoryPlanner(_phase(backend, max_iterations=0), name="llm").plan(_unsafe())
    assert len(backend.calls) == 1 and plan.info["iterations"][0] == 1.0 and plan.info["validated"][0] == 0.0


def test_collect_is_resumable_and_fast_phase_retrieves_from_the_bank(tmp_path):
    batch = concat_batches([
        _unsafe(),
        straight_road_scenario(ego_speed_mps=28.0, scenario_id="free"),
    ])
    with MemoryBank.open(tmp_path / "m.sqlite") as bank:
        backend = ScriptedBackend(default=_reply(40.0, 0.8, "keep distance", tau=2.5))
        stats = collect(_phase(backend), batch, bank)
        assert stats.stored == 2 and stats.skipped == 0 and bank.count() == 2
        again = collect(_phase(ScriptedBackend(default=_reply(40.0, 0.8))), batch, bank)
        assert again.skipped == 2 and again.stored == 0 and bank.count() == 2

        fast_backend = ScriptedBackend(default=json.dumps({"tau": 1.1, "k_np": 41, "k_nf": 3, "k_nl": 0.5,
                                                           "k_bd": 1, "k_cl": 0.5, "lon": 0.8, "lane": 0}))
        # every hand-built scenario is ego 1 of recording "synthetic": allow the same vehicle here
        fast = LetsPiFastPlanner(FastPhase(_advisor(fast_backend), KinematicGoalPredictor(), 10.0,
                                           Retriever(bank, k=2, allow_same_vehicle=True)))
        plan = fast.plan(_unsafe())
        assert fast.last_retrieved[0][0] == "unsafe"  # the identical scenario ranks first
        assert plan.info["n_retrieved"][0] == 2 and np.isfinite(plan.xy_m).all()
        fast_prompt = "".join(m["content"] for m in fast_backend.calls[0])
        physics_prompt = "".join(m["content"] for m in backend.calls[0])
        assert '"k_np": 40.0' in fast_prompt and '"lon": 0.8' in fast_prompt  # the memories' answers
        assert len(fast_prompt) < len(physics_prompt)


def test_ablation_presets_with_a_scripted_model(tmp_path, monkeypatch):
    """Every preset runs end to end (scripted backend via the spec string) and writes its files."""
    from letspi.evaluation.ablations import ABLATION_KINDS, run_ablation
    from letspi.planners.options import PlannerOptions

    batch = concat_batches([_unsafe(), straight_road_scenario(scenario_id="free")])
    bank_path = tmp_path / "m.sqlite"
    with MemoryBank.open(bank_path) as bank:
        collect(_phase(ScriptedBackend(default=_reply(40.0, 0.8))), batch, bank)
    options = PlannerOptions(llm="scripted:default", fast_llm="scripted:default", memory=bank_path,
                             goals="kinematic", llm_cache=False)
    out = tmp_path / "eval"
    for kind in ABLATION_KINDS:
        res = run_ablation(kind, batch, out, options, collect_batch=batch,
                           combinations=[("scripted:default", "scripted:default")])
        assert res and all(r["n"] == 2 for r in res.values()), kind
        assert (out / "ablations" / kind / "metrics.md").exists()
    sizes = json.loads((out / "ablations" / "memory_size.json").read_text())
    assert [p["memory_size"] for p in sizes["points"]] == [0.0, 1.0, 10.0, 50.0, 80.0]
    assert [p["n_memories"] for p in sizes["points"]][-1] == round(0.8 * sizes["n_total"])
    combos = json.loads((out / "ablations" / "llm_combinations.json").read_text())["combinations"]
    assert combos[0]["physics"] == "scripted:default"


def test_a_backend_that_never_answers_leaves_no_experience_to_retrieve_and_is_retried(tmp_path):
    """Defect of 0.1: prose-only replies were stored as *validated* memories carrying the fallback
    parameters, retrieved as experience by the fast phase and never retried."""
    batch = concat_batches([_unsafe(), straight_road_scenario(ego_speed_mps=28.0, scenario_id="free")])
    with MemoryBank.open(tmp_path / "m.sqlite") as bank:
        prose = ScriptedBackend(default="I cannot answer that.")
        stats = collect(_phase(prose), batch, bank)
        assert stats.stored == 2 and stats.validated == 0 and stats.fallback_results == 2
        assert bank.count(validated_only=True) == 0 and bank.count(validated_only=False) == 2
        rows = list(bank.iter_experiences())
        assert all(e.fallback and not e.validated for e in rows)
        retriever = Retriever(bank, k=3, allow_same_vehicle=True)
        assert retriever.retrieve(batch.take([0])) == []
        # resume retries the fallbacks; a real answer replaces them
        good = ScriptedBackend(default=_reply(40.0, 0.8, "keep distance", tau=2.5))
        again = collect(_phase(good), batch, bank)
        assert again.skipped == 0 and again.stored == 2 and again.fallback_results == 0
        assert bank.count(validated_only=False) == 2 and not any(e.fallback for e in bank.iter_experiences())
        assert len(retriever.retrieve(batch.take([0]))) >= 1
        # a finished result is never overwritten by a later fallback
        third = collect(_phase(ScriptedBackend(default="no")), batch, bank)
        assert third.skipped == 2 and third.stored == 0


def test_a_nan_in_a_neighbour_track_does_not_break_collection_or_resume(tmp_path):
    """Defect of 0.1: a NaN matching feature raised IntegrityError on the same scenario at every resume."""
    sc = _unsafe()
    sc.nbr_xy_m[0, 0, 74] = np.nan  # a gap in the leader's track at t = 0, still flagged valid
    with MemoryBank.open(tmp_path / "m.sqlite") as bank:
        backend = ScriptedBackend(default=_reply(40.0, 0.8, tau=2.5))
        assert collect(_phase(backend), sc, bank).stored == 1
        assert collect(_phase(backend), sc, bank).skipped == 1
        (exp,) = bank.iter_experiences()
        assert all(np.isfinite(exp.features)) and exp.features[0] == 0.0  # the leader counts as not visible


def test_collection_keys_keep_configurations_and_datasets_apart(tmp_path):
    batch = _unsafe()
    with MemoryBank.open(tmp_path / "m.sqlite") as bank:
        backend = ScriptedBackend(default=_reply(40.0, 0.8, tau=2.5))
        assert collect(_phase(backend, key="A"), batch, bank).stored == 1
        assert collect(_phase(backend, key="B"), batch, bank).stored == 1  # another configuration: new rows
        regenerated = straight_road_scenario(ego_speed_mps=34.0, neighbours=[VehicleSpec(x0_m=40.0, speed_mps=20.0)],
                                             scenario_id="unsafe")  # same id, other content
        assert collect(_phase(backend, key="A"), regenerated, bank).stored == 1
        assert bank.count(validated_only=False) == 3


def test_retrieval_leaves_out_the_query_vehicle_and_overlapping_windows(tmp_path):
    from dataclasses import replace

    def scene(ego: int, frame0: int, rec: str, sid: str):
        return replace(straight_road_scenario(scenario_id=sid), ego_id=np.array([ego], np.int32),
                       frame0=np.array([frame0], np.int32), recording_key=np.array([rec], dtype=object))

    memories = concat_batches([scene(1, 1000, "r", "same-vehicle-later"), scene(2, 1050, "r", "other-overlapping"),
                               scene(3, 5000, "r", "other-later"), scene(1, 1000, "q", "other-recording")])
    with MemoryBank.open(tmp_path / "m.sqlite") as bank:
        collect(_phase(ScriptedBackend(default=_reply(40.0, 0.8, tau=2.5))), memories, bank)
        query = scene(1, 900, "r", "query")
        got = {e.scenario_id for e, _ in Retriever(bank, k=10).retrieve(query)}
        assert got == {"other-later", "other-recording"}
        leaky = {e.scenario_id for e, _ in Retriever(bank, k=10, allow_same_vehicle=True).retrieve(query)}
        assert leaky == {"same-vehicle-later", "other-overlapping", "other-later", "other-recording"}
