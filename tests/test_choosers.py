"""Choosers that isolate the model: constants, rules, the teacher, the shuffled-scene control (--chooser)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from letspi.analysis.options import OptionOutcomes
from letspi.assembly.build import Builder
from letspi.assembly.planners import build_planner, resolve_planner
from letspi.llm.backends.scripted import ScriptedBackend
from letspi.llm.client import ParamAdvisor
from letspi.method.choosers import (
    ConstantChooser,
    ConstantScore,
    Teacher,
    cautious_choice,
    load_teacher,
    teacher_feature_names,
)
from letspi.method.config import DecisionConfig
from letspi.method.decide import GATE_FEATURE_NAMES, OptionChecks, load_presets
from letspi.method.memory import MemoryBank
from letspi.method.phases import FastPhase
from letspi.method.thresholds import ReflectionThresholds
from letspi.physics.goals import KinematicGoalPredictor
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.planners.llm import LetsPiFastPlanner
from letspi.planners.options import PlannerOptions
from letspi.planners.sf_params import load_sf_params
from letspi.safety.adverse import AdverseSettings
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import concat_batches

NAMES = ("default", "ease", "slow", "brake")
ADVERSE = ("leader-brakes", "cut-in")

TRAIN_MISSING = "letspi-train is not installed (pip install -e packages/letspi-train)"


def _checks(predicted_safe: list[list[int]], adverse_failed: list[list[list[int]]],
            progress_m: list[list[float]]) -> OptionChecks:
    ps = np.array(predicted_safe, bool)
    b, k = ps.shape
    return OptionChecks(NAMES, ADVERSE, ps, np.array(adverse_failed, bool), np.array(progress_m, float),
                        np.full((b, k), np.inf), np.zeros((b, k, 2, 2)), np.zeros((b, k, 2, 2)), np.zeros((b, k, 2)))


def test_the_cautious_tie_break_slows_down_only_where_the_defaults_fail_and_nothing_fails_fewer() -> None:
    progress = [[110.0, 100.0, 90.0, 70.0]] * 4
    checks = _checks(
        predicted_safe=[[1, 1, 1, 1]] * 4,
        adverse_failed=[
            [[0, 0], [0, 0], [0, 0], [0, 0]],  # everything passes: keep the defaults
            [[1, 0], [1, 0], [1, 0], [1, 1]],  # all but brake fail leader-brakes alone: ease (most progress of the tie)
            [[1, 1], [1, 0], [0, 0], [0, 0]],  # slow and brake pass: slow (the rule's choice too)
            [[1, 0], [1, 1], [1, 1], [1, 1]],  # the defaults fail fewest, alone: the defaults
        ],
        progress_m=progress)
    assert cautious_choice(checks).tolist() == [0, 1, 2, 0]
    assert ConstantChooser("ease").choose(concat_batches([_scene(22.0)] * 4), checks, np.zeros(4)).tolist() == [1] * 4
    with pytest.raises(ValueError, match="'coast' is not a preset"):
        ConstantChooser("coast").choose(_scene(22.0), _checks([[1] * 4], [[[0, 0]] * 4], [progress[0]]), np.zeros(1))


def _scene(gap_m: float, scenario_id: str = "s", speed_mps: float = 29.0):  # type: ignore[no-untyped-def]
    return straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(gap_m, speed_mps)],
                                  scenario_id=scenario_id).history()


def _scenes():  # type: ignore[no-untyped-def]
    return concat_batches([_scene(gap, f"s{i}", 29.0 - drop) for i, (gap, drop)
                           in enumerate([(22.0, 0.0), (12.0, 6.0), (8.0, 10.0), (40.0, 2.0), (60.0, 0.0)])])


def test_a_constant_chooser_picks_its_preset_where_the_gate_fires_unless_the_verification_overrules_it(
        tmp_path: Path) -> None:
    MemoryBank.open(tmp_path / "m.sqlite").close()
    options = PlannerOptions(goals="kinematic", memory=tmp_path / "m.sqlite", gate=False, chooser="constant-ease",
                             fast_llm="llamacpp:no-such-model", verify=True)  # never loaded: needs no model
    config = resolve_planner("letspi-fast", options)
    assert config.llm is None and config.chooser is not None  # type: ignore[attr-defined]
    planner = build_planner(config, "ease", builder=Builder(cache=None)).planner
    batch = _scenes()
    plans = planner.plan(batch)
    assert plans.info["llm_calls"].sum() == 0
    decider = DecisionConfig.resolve(None, True, None, None, verify=True).decider(
        load_sf_params(None)[0], ReflectionThresholds())
    context = planner.context(batch)  # type: ignore[attr-defined]
    checks = decider.check(batch, context.goals_xy_m, context.neighbours)
    failed = checks.failed_checks()
    ease = checks.names.index("ease")
    kept = failed[:, ease] <= failed.min(axis=1)
    expected = np.where(kept, "ease", np.array(checks.names)[decider.rule(checks)])
    assert plans.info["decision"].tolist() == expected.tolist()
    assert kept.any() and (~kept).any()  # both cases occur on these scenes
    assert all("chose ease" in r for r in plans.info["reason"])
    # by default (no verification) the answer stands everywhere the gate fires
    default = PlannerOptions(goals="kinematic", memory=tmp_path / "m.sqlite", gate=False, chooser="constant-ease",
                             fast_llm="llamacpp:no-such-model")
    unverified = build_planner(resolve_planner("letspi-fast", default), "ease", builder=Builder(cache=None)).planner
    assert unverified.plan(batch).info["decision"].tolist() == ["ease"] * len(batch)


def test_the_chooser_enters_the_key_and_the_model_s_key_stays(tmp_path: Path) -> None:
    MemoryBank.open(tmp_path / "m.sqlite").close()
    base = PlannerOptions(goals="kinematic", memory=tmp_path / "m.sqlite", fast_llm="scripted:default",
                          prompt_style="choice")
    keys = {name: resolve_planner("letspi-fast", base.replace(chooser=name)).key()
            for name in ("model", "rule", "constant-default", "constant-ease", "cautious", "teacher", "shuffled")}
    assert len(set(keys.values())) == len(keys)
    model = resolve_planner("letspi-fast", base)
    assert model.key() == keys["model"] and "chooser" not in model.identity()
    assert resolve_planner("letspi-fast", base.replace(chooser="rule", fast_llm="scripted:other")).key() == keys["rule"]
    with pytest.raises(ValueError, match="--prompt-style choice"):
        resolve_planner("letspi-fast", base.replace(chooser="shuffled", prompt_style="paper"))


def test_the_shuffled_control_asks_the_model_the_prompt_of_another_consulted_window() -> None:
    params, _ = load_sf_params(None)
    decider = DecisionConfig.resolve(None, True, None, None, verify=True).decider(params, ReflectionThresholds())
    backend = ScriptedBackend(default=json.dumps({"option": "slow"}))
    phase = FastPhase(ParamAdvisor(backend, cache=None), KinematicGoalPredictor(), float(params.r_col_m), None,
                      prompt_style="choice", decider=decider)
    batch = _scenes().take([0, 1, 4])
    planner = LetsPiFastPlanner(phase, shuffle=True)
    assert not planner.proposes_per_scenario  # the harness hands it batches: the donors are in them
    context = planner.context(batch)
    own = [phase.assess(batch.take([i]), context.goals_xy_m[i], context.take([i]).neighbours) for i in range(3)]
    consulted = [i for i in range(3) if own[i].consulted]
    assert len(consulted) >= 2
    plans = planner.plan(batch)
    asked = list(backend.calls)
    donors = [consulted[(j + 1) % len(consulted)] for j in range(len(consulted))]
    assert asked == [own[d].choice_messages() for d in donors]
    for j, i in enumerate(consulted):
        assert plans.info["reason"][i].endswith(f"answered the prompt of {batch.scenario_id[donors[j]]}") or \
            "verified" in plans.info["reason"][i]


def _teacher_data(seed: int = 0) -> tuple[np.ndarray, OptionOutcomes]:
    rng = np.random.default_rng(seed)
    b, k, a = 600, len(NAMES), len(ADVERSE)
    gate_x = rng.normal(size=(b, len(GATE_FEATURE_NAMES)))
    risk = rng.uniform(size=b)
    ps = rng.uniform(size=(b, k)) < 0.8
    af = rng.uniform(size=(b, k, a)) < 0.2
    progress = 100.0 - 8 * np.arange(k) + rng.normal(size=(b, k))
    x = np.concatenate([gate_x, risk[:, None], ps, af.reshape(b, -1), progress - progress[:, :1]], axis=1)
    at_fault = (risk[:, None] + 0.3 * af.any(axis=2) + 0.05 * rng.normal(size=(b, k))) > 0.9
    at_fault[:, 3] = False  # an outcome that never happens: a constant model
    success = progress - progress[:, :1] > -10
    o = OptionOutcomes(collision=at_fault | (rng.uniform(size=(b, k)) < 0.05), at_fault=at_fault, success=success,
                       min_ttc_s=np.full((b, k), np.inf), progress_m=progress, predicted_safe=ps, adverse_failed=af,
                       adverse_applies=np.zeros((b, a), bool))
    return x, o


def test_the_teacher_s_numpy_trees_equal_scikit_learn_on_its_training_inputs(tmp_path: Path) -> None:
    pytest.importorskip("sklearn")
    pytest.importorskip("letspi_train", reason=TRAIN_MISSING)
    from sklearn.ensemble import HistGradientBoostingClassifier

    from letspi_train.finetune.decide_data import OUTCOME_TREES, Weights, fit_teacher

    x, o = _teacher_data()
    teacher = fit_teacher(x, o, NAMES, ADVERSE, Weights())
    assert isinstance(teacher.models["at_fault"][3], ConstantScore) and teacher.models["at_fault"][3].p == 0.0
    p = teacher.probabilities(x)
    assert isinstance(teacher.models["success"][0], ConstantScore)  # the defaults' progress gain is 0: success
    for target, k in (("at_fault", 0), ("at_fault", 1), ("at_fault", 2), ("success", 1), ("success", 2)):
        y = getattr(o, target)[:, k]
        clf = HistGradientBoostingClassifier(max_leaf_nodes=15, early_stopping=False, random_state=0,
                                             **OUTCOME_TREES).fit(x, y)
        np.testing.assert_allclose(p[target][:, k], clf.predict_proba(x)[:, 1], rtol=0, atol=1e-9)
    w = Weights()
    eu = -w.at_fault * p["at_fault"] - w.contact * p["collision"] + p["success"] + w.progress_per_m * x[:, -4:]
    assert teacher.choose_x(x).tolist() == np.argmax(eu, axis=1).tolist()
    assert len(set(teacher.choose_x(x).tolist())) > 1  # the synthetic case is one where it decides
    path = tmp_path / "teacher.json"
    path.write_text(json.dumps(teacher.to_json()))
    back, _ = load_teacher(path)
    np.testing.assert_array_equal(back.expected_utility(x), teacher.expected_utility(x))
    assert back.feature_names == teacher_feature_names(NAMES, ADVERSE)


def test_a_teacher_file_of_another_shape_is_refused_naming_it(tmp_path: Path) -> None:
    data = Teacher(NAMES, ADVERSE, {"at_fault": 8.0, "contact": 2.0, "progress_per_m": 0.01},
                   {t: tuple(ConstantScore(0.1) for _ in NAMES) for t in ("at_fault", "collision", "success")}
                   ).to_json()
    data["feature_names"] = data["feature_names"][:-1]
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"bad\.json: .*feature names"):
        load_teacher(path)


def test_the_shipped_teacher_reads_the_shipped_presets_and_futures_and_decides_on_a_scene() -> None:
    teacher, sha = load_teacher()
    assert teacher.presets == load_presets()[0].names and len(sha) == 64
    assert teacher.adverse_names == tuple(str(a) for a in AdverseSettings().futures)
    params, _ = load_sf_params(None)
    decider = DecisionConfig.resolve(None, True, None, None, verify=True).decider(params, ReflectionThresholds())
    batch = _scenes()
    context = KinematicGoalPredictor().predict_goals(batch).top
    checks = decider.check(batch, context, predict_neighbours(batch, NeighbourPredictionMode.IDM))
    risk = decider.risk_scores(batch, checks)
    x = teacher.inputs(batch, checks, risk)
    assert x.shape == (len(batch), len(teacher.feature_names))
    eu = teacher.expected_utility(x)
    assert np.isfinite(eu).all() and teacher.choose_x(x).tolist() == np.argmax(eu, axis=1).tolist()


@pytest.mark.slow
def test_train_decide_keeps_given_presets_and_gate_and_writes_their_teacher(tmp_path: Path) -> None:
    pytest.importorskip("sklearn")
    pytest.importorskip("letspi_train", reason=TRAIN_MISSING)
    from importlib import resources

    from letspi.scenario.store import save_scenarios
    from letspi_train.finetune.decide_build import build_decision_data
    from letspi_train.finetune.decide_data import HINDSIGHT_COLUMN

    rng = np.random.default_rng(3)
    scenes = concat_batches([straight_road_scenario(
        ego_speed_mps=float(rng.uniform(20.0, 33.0)), scenario_id=f"c{i:02d}",
        neighbours=[VehicleSpec(x0_m=float(rng.uniform(-40.0, 40.0)), speed_mps=float(rng.uniform(12.0, 33.0)),
                                lane_offset=int(rng.integers(-1, 2))) for _ in range(4)]) for i in range(30)])
    scenes = dataclasses.replace(scenes, ego_id=np.arange(30, dtype=scenes.ego_id.dtype))  # 30 vehicles: 5 folds
    path = save_scenarios(scenes, tmp_path / "train.arrow")
    data = Path(str(resources.files("letspi.data")))
    params, _ = load_sf_params(None)
    summary = build_decision_data([path], tmp_path / "td", KinematicGoalPredictor(), params, goals="kinematic",
                                  n_presets=6, consult_share=0.2, keep_share=1.0, refine_weight=2.0,
                                  presets_file=data / "presets.json", risk_model_file=data / "risk_model.json")
    for name in ("presets.json", "risk_model.json"):  # kept as given, byte for byte
        assert (tmp_path / "td" / name).read_text() == (data / name).read_text()
    assert summary["presets"] == list(load_presets()[0].names)
    teacher, _ = load_teacher(tmp_path / "td" / "teacher.json")
    assert teacher.presets == load_presets()[0].names and teacher.provenance["windows"] == 30
    labels = pd.read_parquet(tmp_path / "td" / "labels" / "train" / "labels.parquet")
    assert len(labels) >= 30  # keep_share 1: every window is an example
    outcomes = [json.loads(h) for h in labels[HINDSIGHT_COLUMN]]
    assert all(len(o) == 6 and len(o[0]) == 4 for o in outcomes)
