"""Planner outputs are declared (``PlannerKind.outputs``) and read generically from the declarations."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd
import pytest

from letspi.assembly.build import Builder
from letspi.assembly.planner_table import BUILT_IN, FutureUse, PlannerKind, PlannerOutputError
from letspi.assembly.planners import build_planner, build_planners, built_from_object
from letspi.assembly.resolve import Resolver
from letspi.evaluation.harness import evaluate
from letspi.evaluation.summary import known_outputs, outputs_reference_markdown, timing_summary
from letspi.keyed import Config
from letspi.method.memory import MemoryBank
from letspi.method.phases import collect
from letspi.metrics.registry import Agg
from letspi.planners.base import PlanBatch
from letspi.planners.options import DEFAULT_OPTIONS
from letspi.planners.outputs import by_column, column, info_columns, output, over_replans, undeclared
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import ScenarioBatch, concat_batches
from letspi.simulation.store import CLOSED_LOOP_OUTPUTS

SCRIPTED = "scripted:default"


def _scenes(n: int = 4) -> ScenarioBatch:
    return concat_batches([straight_road_scenario(ego_speed_mps=24.0 + 2 * i, scenario_id=f"s{i}",
                                                  neighbours=[VehicleSpec(x0_m=25.0 + 5 * i, speed_mps=20.0)])
                           for i in range(n)])


def test_every_built_in_kind_declares_every_value_it_reports(tmp_path: Path) -> None:
    batch = _scenes()
    options = DEFAULT_OPTIONS.replace(llm=SCRIPTED, fast_llm=SCRIPTED, goals="kinematic", llm_cache=False,
                                      memory=tmp_path / "m.sqlite", allow_same_vehicle=True)
    phase, _ = Builder(cache=None).memory_phase(Resolver(options).memory_phase())
    with MemoryBank.open(tmp_path / "m.sqlite") as bank:
        collect(phase, batch, bank)
    plain = [k.name for k in BUILT_IN.kinds if not k.uses_llm and k.name != "mlp"]  # mlp needs trained weights
    planners = build_planners(plain, DEFAULT_OPTIONS)
    llm = [k.name for k in BUILT_IN.kinds if k.uses_llm]
    planners += build_planners(llm, options)
    # the decision step's outputs with a model: the choice prompt
    planners += build_planners(["fast-choice=letspi-fast", "memory-choice=letspi-memory"],
                               options.replace(prompt_style="choice"))
    reported = 0
    for built in planners:
        plan = built.planner.plan(batch if built.reads_future else batch.history())
        assert not undeclared(plan.info, built.outputs), (built.name, undeclared(plan.info, built.outputs))
        built.check_outputs(plan.info)
        reported += len(plan.info)
    assert reported > 100


def test_columns_follow_the_declaration() -> None:
    flag = output("flag", "bool", "bool", "a flag", Agg("flag_pct", "pct"))
    assert column(flag) == "info_flag" and over_replans(flag) == "info_flag_mean_over_replans"
    cols = info_columns({"flag": np.array([True, False]), "w": np.ones((2, 3))})
    assert list(cols) == ["info_flag", "info_w_0", "info_w_1", "info_w_2"]
    named = next(o for o in CLOSED_LOOP_OUTPUTS if o.name == "n_replans")
    assert column(named) == "n_replans"  # a column the closed loop writes itself


def test_the_summary_aggregates_whatever_is_declared() -> None:
    leader = output("leader", "bool", "bool", "a leader", Agg("leader_pct", "pct"))
    gap = output("gap_m", "m", "float64", "a gap", Agg("gap_mean_m", "finite_mean"))
    frame = pd.DataFrame({"inference_s": [0.1, 0.2, 0.3, 0.4], "info_leader": [True, True, False, True],
                          "info_gap_m": [10.0, np.nan, 20.0, 30.0], "info_other": [1, 2, 3, 4]})
    out = timing_summary(frame, 1.0, by_column([leader, gap]))
    assert out["leader_pct"] == 75.0 and out["gap_mean_m"] == 20.0 and "other" not in str(out)
    assert out["inference_s"] == pytest.approx(0.25) and out["model_load_s"] == 1.0
    # the built-in declarations: the shield's share and the decision step's consultations
    shield = pd.DataFrame({"inference_s": [0.1, 0.1], "info_shielded": [1.0, 0.0], "info_consulted": [True, True]})
    got = timing_summary(shield, 0.0, known_outputs())
    assert got["shielded_pct"] == 50.0 and got["consulted_pct"] == 100.0
    # closed loop: the calls of all replans win over the t = 0 plan's
    loop = pd.DataFrame({"inference_s": [0.1], "info_llm_calls": [1.0], "info_llm_calls_total": [5.0],
                         "info_llm_in_force_mean_over_replans": [0.25], "n_replans": [25]})
    got = timing_summary(loop, 0.0, known_outputs())
    assert got["llm_calls_per_scenario"] == 5.0 and got["llm_in_force_pct"] == 25.0
    assert got["replans_per_scenario"] == 25.0


class _Reporter:
    name, batch_size = "reporter", 64

    def __init__(self, key: str) -> None:
        self.key = key

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        b = len(batch)
        xy = np.zeros((b, 125, 2))
        return PlanBatch(xy_m=xy, vxy_mps=xy.copy(), goals_xy_m=np.zeros((b, 2)), info={self.key: np.ones(b, bool)})


class _ReporterConfig(Config):
    kind: Literal["reporter"] = "reporter"
    version: str = "1"
    report: str = "leader"


def _kind() -> PlannerKind[_ReporterConfig]:
    return PlannerKind("reporter", "reports one flag", _ReporterConfig, lambda r: _ReporterConfig(),
                       lambda b, c, label: (_Reporter(c.report), 0.0), future=FutureUse.NEVER,
                       outputs=(output("leader", "bool", "bool", "a leader", Agg("leader_pct", "pct")),))


def test_a_declared_output_reaches_metrics_json_with_its_interval(tmp_path: Path) -> None:
    table = BUILT_IN.with_kinds(_kind())
    built = build_planner(_ReporterConfig(), "reporter", table=table)
    results = evaluate([built], _scenes(), tmp_path / "ev")
    assert results["reporter"]["leader_pct"] == 100.0


def test_an_undeclared_value_is_refused_naming_the_kind_and_the_fix(tmp_path: Path) -> None:
    table = BUILT_IN.with_kinds(_kind())
    built = build_planner(_ReporterConfig(report="surprise"), "reporter", table=table)
    with pytest.raises(PlannerOutputError, match=r"planner kind 'reporter' reported per-scenario info it does not "
                                                 r"declare: surprise; add each to its PlannerKind\(outputs=...\)"):
        evaluate([built], _scenes(), tmp_path / "ev")
    assert not (tmp_path / "ev" / "per_scenario").exists()  # nothing stored


def test_the_reference_lists_every_declared_output() -> None:
    text = outputs_reference_markdown()
    for o in (*BUILT_IN.outputs(), *CLOSED_LOOP_OUTPUTS):
        assert f"| `{column(o)}` |" in text


def test_a_planner_object_declares_its_outputs_or_leaves_them_unchecked(tmp_path: Path) -> None:
    bare = _Reporter("leader")
    results = evaluate([built_from_object(bare)], _scenes(), tmp_path / "bare")
    assert "leader_pct" not in results["reporter"]  # stored, not aggregated: nothing declares it
    declaring = _Reporter("leader")
    declaring.outputs = (output("leader", "bool", "bool", "a leader", Agg("leader_pct", "pct")),)  # type: ignore[attr-defined]
    assert evaluate([built_from_object(declaring)], _scenes(), tmp_path / "declared")["reporter"]["leader_pct"] == 100.0
    wrong = _Reporter("surprise")
    wrong.outputs = declaring.outputs  # type: ignore[attr-defined]
    with pytest.raises(PlannerOutputError, match="does not declare: surprise"):
        evaluate([built_from_object(wrong)], _scenes(), tmp_path / "wrong")
