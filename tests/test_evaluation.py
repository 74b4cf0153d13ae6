"""The evaluation harness: outputs, resume after a crash, guard against mixing scenario sets."""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import pytest

from letspi.evaluation.harness import EvaluationDirError, evaluate, load_planner_results
from letspi.planners.base import PlanBatch
from letspi.planners.cv import ConstantVelocityPlanner
from letspi.planners.human import HumanPlanner
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import ScenarioBatch, concat_batches

PAPER_KEYS = ("n", "ttc_s", "cr_pct", "pet_s", "min_dist_m", "lt_pct", "sr_pct", "inference_s")


def _batch(n: int = 6) -> ScenarioBatch:
    return concat_batches([
        straight_road_scenario(scenario_id=f"s{i}", neighbours=[VehicleSpec(20.0 + i, 28.0)])
        for i in range(n)
    ])


@dataclass
class CrashingPlanner:
    """CV planner that dies on its ``crash_on``-th call (simulates a crash mid-run)."""

    crash_on: int
    name: str = "crashy"
    batch_size: int = 2
    calls: int = 0

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        self.calls += 1
        if self.calls == self.crash_on:
            raise RuntimeError("boom")
        return ConstantVelocityPlanner().plan(batch)


def test_outputs_have_the_documented_keys(tmp_path):
    res = evaluate([HumanPlanner(), ConstantVelocityPlanner()], _batch(), tmp_path)
    on_disk = json.loads((tmp_path / "metrics.json").read_text())["planners"]
    assert set(on_disk) == {"human", "cv"}
    for key in PAPER_KEYS:
        assert key in on_disk["human"]
    assert on_disk["human"]["n"] == 6 and on_disk["human"]["cr_pct"] == 0.0
    assert res["cv"]["n"] == 6
    table = (tmp_path / "metrics.md").read_text().splitlines()
    assert table[2].startswith("| human |") and table[3].startswith("| cv |")
    rows = load_planner_results(tmp_path, "human")
    assert sorted(rows["scenario_id"]) == [f"s{i}" for i in range(6)]
    assert (rows["inference_s"] >= 0).all()


def test_crash_then_rerun_resumes_without_duplicates(tmp_path):
    batch = _batch(6)
    crashy = CrashingPlanner(crash_on=2)
    with pytest.raises(RuntimeError, match="boom"):
        evaluate([crashy], batch, tmp_path)
    done = load_planner_results(tmp_path, "crashy")
    assert len(done) == 2  # the first chunk survived the crash
    again = CrashingPlanner(crash_on=99)
    evaluate([again], batch, tmp_path)
    assert again.calls == 2  # only the 4 missing scenarios, in chunks of 2
    rows = load_planner_results(tmp_path, "crashy")
    assert sorted(rows["scenario_id"]) == [f"s{i}" for i in range(6)]
    third = CrashingPlanner(crash_on=99)
    evaluate([third], batch, tmp_path)
    assert third.calls == 0


def test_refuses_to_mix_scenario_sets(tmp_path):
    evaluate([HumanPlanner()], _batch(3), tmp_path)
    with pytest.raises(EvaluationDirError, match="holds results for other scenarios"):
        evaluate([HumanPlanner()], _batch(4), tmp_path)


def test_later_planners_join_the_table(tmp_path):
    evaluate([HumanPlanner()], _batch(3), tmp_path)
    evaluate([ConstantVelocityPlanner()], _batch(3), tmp_path)
    on_disk = json.loads((tmp_path / "metrics.json").read_text())["planners"]
    assert set(on_disk) == {"human", "cv"}
    assert np.isfinite(on_disk["cv"]["min_dist_m"])


def test_refuses_to_mix_configurations_of_one_planner(tmp_path):
    @dataclass
    class Configured:
        config_key: str
        name: str = "p"
        batch_size: int = 8

        def plan(self, batch: ScenarioBatch) -> PlanBatch:
            return ConstantVelocityPlanner().plan(batch)

    evaluate([Configured("a")], _batch(3), tmp_path)
    evaluate([Configured("a")], _batch(3), tmp_path)  # same configuration: resumes
    with pytest.raises(EvaluationDirError, match="with another configuration"):
        evaluate([Configured("b")], _batch(3), tmp_path)
