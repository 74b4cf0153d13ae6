"""The evaluation harness: outputs, keys, refusals, stored plans, resume after a crash or a kill -9."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from letspi.assembly.planners import BuiltPlanner, build_planners
from letspi.evaluation.harness import EvaluationSettings, evaluate
from letspi.evaluation.results import EvaluationDirError, load_planner_results, load_plans
from letspi.evaluation.summary import timing_summary
from letspi.metrics.config import MetricsConfig
from letspi.planners.base import PlanBatch
from letspi.planners.cv import ConstantVelocityPlanner, CvConfig
from letspi.planners.human import HumanConfig
from letspi.planners.options import PlannerOptions
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.store import save_scenarios
from letspi.scenario.types import ScenarioBatch, concat_batches

PAPER_KEYS = ("n", "ttc_s", "cr_pct", "pet_s", "min_dist_m", "lt_pct", "sr_pct", "inference_s")


def _batch(n: int = 6, speed_mps: float = 28.0) -> ScenarioBatch:
    return concat_batches([
        straight_road_scenario(scenario_id=f"s{i}", neighbours=[VehicleSpec(20.0 + i, speed_mps)])
        for i in range(n)
    ])


def _built(*kinds: str) -> list[BuiltPlanner]:
    return build_planners(list(kinds), PlannerOptions(goals="kinematic"))


@dataclass
class CrashingPlanner:
    """CV planner that dies on its ``crash_on``-th call (simulates a crash mid-run)."""

    crash_on: int
    name: str = "crashy"
    batch_size: int = 2
    reads_future: bool = False
    calls: int = 0

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        self.calls += 1
        if self.calls == self.crash_on:
            raise RuntimeError("boom")
        return ConstantVelocityPlanner().plan(batch)


def _crashy(crash_on: int) -> BuiltPlanner:
    return BuiltPlanner("crashy", CvConfig(), CrashingPlanner(crash_on))


def test_outputs_have_the_documented_keys(tmp_path: Path) -> None:
    res = evaluate(_built("human", "cv"), _batch(), tmp_path, EvaluationSettings(scenarios_file="mem"))
    on_disk = json.loads((tmp_path / "metrics.json").read_text())
    assert set(on_disk["planners"]) == {"human", "cv"}
    for key in PAPER_KEYS:
        assert key in on_disk["planners"]["human"]
    assert on_disk["planners"]["human"]["n"] == 6 and on_disk["planners"]["human"]["cr_pct"] == 0.0
    assert res["cv"]["n"] == 6
    run = json.loads((tmp_path / "run.json").read_text())
    assert set(run["identity"]) == {"format", "mode", "dataset_digest", "metrics_config"}
    assert on_disk["run"]["key"] == run["key"]
    config = json.loads((tmp_path / "per_scenario" / "cv" / "config.json").read_text())
    assert config["kind"] == "cv" and config["key"] == CvConfig().key()
    table = (tmp_path / "metrics.md").read_text().splitlines()
    assert table[2].startswith("| human |") and table[3].startswith("| cv |")
    rows = load_planner_results(tmp_path, "human")
    assert list(rows["scenario_id"]) == [f"s{i}" for i in range(6)]
    assert (rows["inference_s"] >= 0).all()


def test_stored_plans_are_the_plans_that_were_scored(tmp_path: Path) -> None:
    batch = _batch(3)
    evaluate(_built("cv"), batch, tmp_path)
    plans = load_plans(tmp_path, "cv")
    direct = ConstantVelocityPlanner().plan(batch.history())
    for i, sid in enumerate(batch.scenario_id):
        xy, vxy, goal = plans[str(sid)]
        np.testing.assert_allclose(xy, direct.xy_m[i], atol=1e-4)  # float32 storage
        np.testing.assert_allclose(vxy, direct.vxy_mps[i], atol=1e-4)
        np.testing.assert_allclose(goal, direct.goals_xy_m[i], atol=1e-4)


def test_crash_then_rerun_resumes_without_duplicates(tmp_path: Path) -> None:
    batch = _batch(6)
    with pytest.raises(RuntimeError, match="boom"):
        evaluate([_crashy(2)], batch, tmp_path)
    assert len(load_planner_results(tmp_path, "crashy")) == 2  # the first chunk survived the crash
    again = _crashy(99)
    evaluate([again], batch, tmp_path)
    assert again.planner.calls == 2  # type: ignore[attr-defined]  # only the 4 missing, in chunks of 2
    rows = load_planner_results(tmp_path, "crashy")
    assert list(rows["scenario_id"]) == [f"s{i}" for i in range(6)]
    third = _crashy(99)
    evaluate([third], batch, tmp_path)
    assert third.planner.calls == 0  # type: ignore[attr-defined]


def test_refuses_other_scenarios_even_with_the_same_ids(tmp_path: Path) -> None:
    evaluate(_built("human"), _batch(3), tmp_path, EvaluationSettings(scenarios_file="a.arrow"))
    with pytest.raises(EvaluationDirError, match="other scenarios: the directory holds 3 scenarios from a.arrow"):
        evaluate(_built("human"), _batch(4), tmp_path, EvaluationSettings(scenarios_file="b.arrow"))
    # regenerated data: the same scenario ids, other content (a faster leader) -> refused, not mixed
    with pytest.raises(EvaluationDirError, match="dataset digest"):
        evaluate(_built("human"), _batch(3, speed_mps=31.0), tmp_path, EvaluationSettings(scenarios_file="a.arrow"))


def test_refuses_another_metrics_configuration(tmp_path: Path) -> None:
    evaluate(_built("cv"), _batch(3), tmp_path)
    with pytest.raises(EvaluationDirError, match=r"metrics_config.low_ttc_s: 2.0 -> 3.0"):
        evaluate(_built("cv"), _batch(3), tmp_path, EvaluationSettings(metrics=MetricsConfig(low_ttc_s=3.0)))


def test_later_planners_join_the_table(tmp_path: Path) -> None:
    evaluate(_built("human"), _batch(3), tmp_path)
    evaluate(_built("cv"), _batch(3), tmp_path)
    on_disk = json.loads((tmp_path / "metrics.json").read_text())["planners"]
    assert set(on_disk) == {"human", "cv"}
    assert np.isfinite(on_disk["cv"]["min_dist_m"])


def test_another_configuration_of_one_planner_is_refused_or_labelled(tmp_path: Path) -> None:
    batch = _batch(3)
    evaluate(_built("sf"), batch, tmp_path)
    evaluate(_built("sf"), batch, tmp_path)  # same configuration: resumes
    cv_neighbours = build_planners(["sf"], PlannerOptions(goals="kinematic", neighbour_mode="constant_velocity"))
    hint = f"sf-{cv_neighbours[0].key[:6]}=sf"  # a label of its own (its key's start), the kind as given
    with pytest.raises(EvaluationDirError, match=rf"neighbours: idm -> constant_velocity.*\(--planner {hint}\)"):
        evaluate(cv_neighbours, batch, tmp_path)
    labelled = build_planners([hint], PlannerOptions(goals="kinematic", neighbour_mode="constant_velocity"))
    res = evaluate(labelled, batch, tmp_path)  # the hint works
    assert res[hint.split("=")[0]]["config_key"] != res["sf"]["config_key"]


def test_timing_excludes_cached_rows() -> None:
    frame = pd.DataFrame({"inference_s": [5.0, 7.0, 0.001, 0.002], "info_llm_cached": [False, False, True, True],
                          "info_llm_original_latency_s": [5.0, 7.0, 6.0, 6.0], "info_llm_calls": [1, 2, 1, 1],
                          "info_fallback": [False, False, False, True]})
    t = timing_summary(frame, load_s=1.5)
    assert t["inference_s"] == pytest.approx(6.0) and t["inference_n"] == 2 and t["inference_cached_n"] == 2
    assert t["llm_original_latency_s"] == pytest.approx(6.0) and t["model_load_s"] == 1.5
    assert t["fallback_pct"] == pytest.approx(25.0)


_KILL_SCRIPT = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from letspi.evaluation.harness import EvaluationSettings, evaluate
    from letspi.planners.sf import SocialForcePlanner
    from letspi.assembly.planners import build_planners
    from letspi.planners.options import PlannerOptions
    from letspi.scenario.store import load_scenarios

    class Slow:
        # the sf planner, slowed down so the parent can kill the process while it writes parts
        def __init__(self, inner):
            self.inner, self.name, self.batch_size, self.reads_future = inner, inner.name, 3, False
        def plan(self, batch):
            time.sleep(0.05)
            return self.inner.plan(batch)

    built = build_planners(["sf"], PlannerOptions(goals="kinematic"))[0]
    built.planner = Slow(built.planner)
    evaluate([built], load_scenarios(Path(sys.argv[1])), Path(sys.argv[2]),
             EvaluationSettings(scenarios_file=sys.argv[1]))
""")


@pytest.mark.slow  # 25 s each on a loaded 2-core machine (notes/reliability.md)
@pytest.mark.parametrize("kill_after_s", [0.5, 1.2])
def test_kill_9_during_writing_then_rerun_equals_an_uninterrupted_run(tmp_path: Path, kill_after_s: float) -> None:
    batch = _batch(120)  # 40 parts of 3, >= 2 s of work: the kill lands mid-run
    scen = save_scenarios(batch, tmp_path / "s.arrow")
    script = tmp_path / "run.py"
    script.write_text(_KILL_SCRIPT)
    killed, clean = tmp_path / "killed", tmp_path / "clean"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.Popen([sys.executable, str(script), str(scen), str(killed)], env=env)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not list((killed / "per_scenario" / "sf").glob("part-*.parquet")):
        time.sleep(0.02)
    time.sleep(kill_after_s)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    n_parts = len(list((killed / "per_scenario" / "sf").glob("part-*.parquet")))
    assert 0 < n_parts < 40, "the kill should land mid-run"
    subprocess.run([sys.executable, str(script), str(scen), str(killed)], env=env, check=True)
    subprocess.run([sys.executable, str(script), str(scen), str(clean)], env=env, check=True)
    a = load_planner_results(killed, "sf").drop(columns=["inference_s"])
    b = load_planner_results(clean, "sf").drop(columns=["inference_s"])
    pd.testing.assert_frame_equal(a, b)
    assert not list((killed / "per_scenario" / "sf").glob(".*.tmp"))  # no torn temporaries left
    ma = json.loads((killed / "metrics.json").read_text())["planners"]["sf"]
    mb = json.loads((clean / "metrics.json").read_text())["planners"]["sf"]
    timing = {k for k in ma if k.startswith(("inference", "model_load"))}
    assert {k: v for k, v in ma.items() if k not in timing} == {k: v for k, v in mb.items() if k not in timing}


def test_non_oracle_planners_get_the_history_only(tmp_path: Path) -> None:
    seen: list[int] = []

    @dataclass
    class Peek:
        name: str = "peek"
        batch_size: int = 8

        def plan(self, batch: ScenarioBatch) -> PlanBatch:
            seen.append(batch.n_frames)
            return ConstantVelocityPlanner().plan(batch)

    evaluate([BuiltPlanner("peek", CvConfig(), Peek())], _batch(2), tmp_path)
    assert seen == [75]
    seen.clear()
    # whether a planner sees the future is its kind's (the table's) to say: human's configuration reads it
    evaluate([BuiltPlanner("peek-oracle", HumanConfig(), Peek())], _batch(2), tmp_path)
    assert seen == [200]
