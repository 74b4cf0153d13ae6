"""The decision step's option checks (``letspi.method.decide``) and the cached option outcomes
(``letspi.analysis.options``) on synthetic scenes."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from letspi.analysis.options import OptionRun, load_option_run, random_option_table, score_options
from letspi.learned.logistic import LogisticModel
from letspi.llm.backends.scripted import ScriptedBackend
from letspi.llm.client import ParamAdvisor
from letspi.method.decide import (
    GATE_FEATURE_NAMES,
    Decider,
    OptionTable,
    RiskGate,
    check_options,
    defaults_vector,
    load_presets,
    plan_options,
    with_defaults,
)
from letspi.method.phases import FastPhase, MemoryPhase
from letspi.method.reflection import Proposal, ReflectionContext, reflect
from letspi.method.thresholds import ReflectionThresholds
from letspi.metrics.compute import compute_outcomes
from letspi.physics.goals import KinematicGoalPredictor
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.params import SocialForceParams
from letspi.safety.adverse import AdverseSettings, adverse_futures, check_futures
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import concat_batches

PARAMS = SocialForceParams(tau_s=2.0, k_np=21.0, k_nf=9.0, k_nl=0.2, k_boundary=0.5, k_cline=0.5, r_col_m=5.0)


def _table() -> OptionTable:
    d = defaults_vector(PARAMS)
    slow, left = d.copy(), d.copy()
    slow[6] = 1.0  # goal 30 % shorter
    left[7] = -1.0
    return OptionTable(("default", "slow", "lane-left"), np.stack([d, slow, left]))


def _scenes():  # type: ignore[no-untyped-def]
    return concat_batches([
        straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(22.0, 30.0)], scenario_id="leader"),
        straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(-40.0, 30.0, lane_offset=1)],
                               scenario_id="free"),
    ])


def test_check_options_agrees_with_checking_each_plan_by_hand() -> None:
    batch = _scenes()
    hist = batch.history()
    goals = KinematicGoalPredictor().predict_goals(hist).top
    pred = predict_neighbours(hist, NeighbourPredictionMode.IDM)
    table = _table()
    chk = check_options(hist, goals, pred, table, 5.0)
    assert chk.names == table.names and chk.adverse_names == ("leader-brakes", "cut-in", "follower-keeps")
    xy, vxy, _ = plan_options(hist, table.values, goals, pred, 5.0)
    np.testing.assert_array_equal(chk.xy_m.reshape(-1, *xy.shape[1:]), xy)
    np.testing.assert_allclose(chk.progress_m, xy[:, -1, 0].reshape(2, 3))
    # scene 0 by hand: the default plan follows the leader and hits it when it brakes hard
    pred_take = pred.take(slice(0, 1))
    fut = adverse_futures(hist.take([0]), pred_take)
    by_hand = check_futures(hist.take([0]), xy[:1], vxy[:1], pred_take, fut)
    assert chk.adverse_failed[0, 0, 0] == by_hand.collision[0, 1]
    assert chk.failed_names(0, 0) == ["leader-brakes"]
    assert not chk.adverse_failed[1].any()  # nobody ahead, nobody drifting, the follower is far
    assert chk.passes_all()[1].all() and chk.failed_checks()[0, 0] >= 1


def test_score_options_pairs_hindsight_and_checks_and_the_run_resumes(tmp_path: Path) -> None:
    batch = _scenes()
    table = _table()
    gp = KinematicGoalPredictor()
    scored = score_options(batch, table, gp, PARAMS, checks=True)
    hist = batch.history()
    goals = gp.predict_goals(hist).top
    pred = predict_neighbours(hist, NeighbourPredictionMode.IDM)
    xy, vxy, _ = plan_options(hist, table.values, goals, pred, 5.0)
    out = compute_outcomes(batch.take(np.repeat(np.arange(2), 3)), xy, vxy)
    np.testing.assert_array_equal(scored.collision, out.collision.reshape(2, 3))
    np.testing.assert_array_equal(scored.adverse_failed, check_options(hist, goals, pred, table, 5.0).adverse_failed)
    with pytest.raises(ValueError, match="recorded future"):
        score_options(hist, table, gp, PARAMS)
    run = OptionRun.create(batch, table, tmp_path / "o", gp, PARAMS, goals="kinematic", checks=True, chunk=1)
    first = run.run()
    np.testing.assert_array_equal(first.adverse_failed, scored.adverse_failed)
    (tmp_path / "o" / "parts" / "part-000001.npz").unlink()  # as if killed after the first chunk
    again = run.run()
    np.testing.assert_array_equal(again.collision, first.collision)
    t, o, manifest = load_option_run(tmp_path / "o")
    assert t.names == table.names and manifest["n_windows"] == 2 and len(o) == 2
    other = OptionRun.create(batch, random_option_table(PARAMS, 4, 0), tmp_path / "o", gp, PARAMS, goals="kinematic")
    with pytest.raises(ValueError, match="other settings"):
        other.run()


def test_presets_file_and_own_defaults(tmp_path: Path) -> None:
    table = _table()
    path = tmp_path / "p.json"
    path.write_text(json.dumps({"format": "letspi-presets/1", **table.to_json()}))
    loaded, record = load_presets(path)
    assert loaded.names == table.names and record["format"] == "letspi-presets/1"
    other = SocialForceParams(tau_s=1.5, k_np=30.0, k_nf=9.0, k_nl=0.2, k_boundary=0.5, k_cline=0.5, r_col_m=5.0)
    mine = with_defaults(loaded, other)
    np.testing.assert_array_equal(mine.values[0], defaults_vector(other))
    np.testing.assert_array_equal(mine.values[1:], table.values[1:])
    path.write_text(json.dumps({"format": "letspi-presets/1", "names": ["slow"], "values": [table.values[1].tolist()]}))
    with pytest.raises(ValueError, match="first preset must be 'default'"):
        load_presets(path)


# --- the decision step in the phases ---------------------------------------------------------------


def _gate(threshold: float, logit: float) -> RiskGate:
    """A gate whose score is the constant sigmoid(logit) (zero weights)."""
    d = len(GATE_FEATURE_NAMES)
    model = LogisticModel(GATE_FEATURE_NAMES, ("safe", "at_fault"), np.zeros(d), np.ones(d), np.zeros((d, 2)),
                          np.array([0.0, logit]))
    return RiskGate(model, threshold)


def _decider(gate: RiskGate | None, adverse: AdverseSettings | None = None) -> Decider:
    return Decider(_table(), 5.0, ReflectionThresholds(), adverse or AdverseSettings(), gate)


def _leader_scene():  # type: ignore[no-untyped-def]
    return straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(22.0, 30.0)]).history()


def test_reflection_refines_a_plan_that_fails_an_adverse_future_and_says_which() -> None:
    scene = _leader_scene()
    slow = Proposal(params=PARAMS, lon_factor=1.0)

    def propose(ctx: ReflectionContext) -> Proposal:
        if ctx.iteration == 0:
            return Proposal(params=PARAMS)
        assert ctx.adverse is not None and ctx.adverse.failed == ("leader-brakes",)
        assert ctx.adverse.text().startswith("fails leader-brakes (")
        return slow

    result = reflect(scene, propose, base_goal_xy_m=np.array([150.0, 0.0]), adverse=AdverseSettings())
    first = result.iterations[0]
    assert first.predicted_safe and not first.safe and first.adverse is not None
    assert first.to_dict()["adverse_failed"] == ["leader-brakes"]
    assert result.validated  # in the paper's sense: safe against the prediction
    without = reflect(scene, lambda ctx: Proposal(params=PARAMS), base_goal_xy_m=np.array([150.0, 0.0]))
    assert without.n_refinements == 0 and without.final.adverse is None  # the paper's reflection


def test_fast_phase_gate_keeps_the_defaults_without_a_call_or_asks_for_a_preset() -> None:
    scene = _leader_scene()
    goal = np.array([150.0, 0.0])
    quiet = ScriptedBackend()  # any call would fail: the script is empty
    phase = FastPhase(ParamAdvisor(quiet, cache=None), KinematicGoalPredictor(), 5.0, None, prompt_style="choice",
                      decider=_decider(_gate(0.9, 0.0)))
    proposal, _ = phase.propose_retrieved(scene, goal)
    assert quiet.calls == [] and proposal.meta["decision"] == "default" and not proposal.meta["consulted"]
    assert proposal.meta["risk_score"] == pytest.approx(0.5) and proposal.lon_factor == pytest.approx(0.4)
    asked = ScriptedBackend(['{"option": "slow"}'])
    phase = FastPhase(ParamAdvisor(asked, cache=None), KinematicGoalPredictor(), 5.0, None, prompt_style="choice",
                      decider=_decider(_gate(0.4, 0.0)))
    proposal, _ = phase.propose_retrieved(scene, goal)
    assert proposal.meta["decision"] == "slow" and proposal.meta["consulted"] and proposal.lon_factor == 1.0
    assert proposal.meta["reason"] == "risk 50.0 % >= gate 40.0 %; default fails leader-brakes; chose slow (passes " \
        "every check)"
    prompt = asked.calls[0][-1]["content"]
    assert "default: leader-brakes;" in prompt and "slow: " in prompt
    assert asked.schemas[0] is not None and asked.schemas[0]["properties"]["option"]["enum"] == list(_table().names)


def test_memory_phase_choice_refinement_names_the_rejected_preset_and_the_failed_future() -> None:
    scene = _leader_scene()
    backend = ScriptedBackend(['{"option": "default"}', '{"option": "slow"}'])
    phase = MemoryPhase(ParamAdvisor(backend, cache=None), KinematicGoalPredictor(), 5.0, "k", prompt_style="choice",
                        decider=_decider(None))
    result = phase.run(scene, np.array([150.0, 0.0]))
    assert [it.proposal.meta["decision"] for it in result.iterations] == ["default", "slow"]
    refine = backend.calls[1][-1]["content"]
    assert "Rejected: default\nCheck: failed leader-brakes" in refine


def test_verification_replaces_a_choice_that_fails_more_checks_than_another_preset() -> None:
    """The leader 22 m ahead at the ego's speed: the defaults fail leader-brakes, slow passes. A model
    answering default is overruled by the rule's choice; ease (failing the same check as every faster
    option) or slow stand; off, the model's answer stands."""
    scene = _leader_scene()
    goal = np.array([150.0, 0.0])
    decider = _decider(_gate(0.4, 0.0))
    checks = decider.check(scene, goal.reshape(1, 2), predict_neighbours(scene, NeighbourPredictionMode.IDM))
    failed = checks.failed_checks()[0]
    assert failed[0] > failed.min()  # the scene's premise: the defaults fail a check some preset passes
    rule = checks.names[int(decider.rule(checks)[0])]
    verifying = replace(decider, verify=True)
    assert verifying.verified(checks, "default") == rule != "default"
    assert verifying.verified(checks, rule) == rule and verifying.verified(checks, "custom") == "custom"
    for verify, expected in ((True, rule), (False, "default")):
        asked = ScriptedBackend(['{"option": "default"}'])
        phase = FastPhase(ParamAdvisor(asked, cache=None), KinematicGoalPredictor(), 5.0, None, prompt_style="choice",
                          decider=replace(decider, verify=verify))
        proposal, _ = phase.propose_retrieved(scene, goal)
        assert len(asked.calls) == 1 and proposal.meta["decision"] == expected
        reply = dict(zip(checks.names, decider.presets.values, strict=True))[expected]
        assert proposal.lon_factor == pytest.approx(reply[-2]) and proposal.params.tau_s == pytest.approx(reply[0])
        if verify:
            assert proposal.meta["reason"].endswith(f"default fails leader-brakes; kept default; verified: {rule} "
                                                    "fails fewer checks (passes every check)")
