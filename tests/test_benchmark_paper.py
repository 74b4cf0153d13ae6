"""``letspi benchmark paper``: the split of a suite's windows, and the four tables end to end with a scripted
model on hand-built scenes (control flow; the measured tables are docs/reproduction.md's)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from letspi.benchmark.paper import PaperData, PaperSettings, run_paper, split_suite
from letspi.metrics.config import MetricsConfig
from letspi.planners.options import PlannerOptions
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.split import vehicle_keys
from letspi.scenario.store import save_scenarios
from letspi.scenario.types import ScenarioBatch, concat_batches


def _scenes(n: int, first_ego: int) -> ScenarioBatch:
    """``n`` scenes of ``n`` ego vehicles: leaders 30-60 m ahead at 20 m/s, the ego at 30 m/s."""
    scenes = [straight_road_scenario(ego_speed_mps=30.0, scenario_id=f"s{first_ego + i}",
                                     neighbours=[VehicleSpec(x0_m=30.0 + 10.0 * (i % 4), speed_mps=20.0)])
              for i in range(n)]
    batch = concat_batches(scenes)
    return replace(batch, ego_id=np.arange(first_ego, first_ego + n, dtype=batch.ego_id.dtype))


def test_split_keeps_each_vehicle_on_one_side_and_draws_the_sizes():
    batch = _scenes(40, 1)
    batch = replace(batch, ego_id=np.repeat(np.arange(10, dtype=batch.ego_id.dtype), 4))  # 10 vehicles, 4 windows
    settings = PaperSettings(eval_windows=12, memory_windows=5, memory_phase_windows=3, memory_share=0.3, seed=4)
    evaluated, memory, phase = split_suite(batch, settings)
    keys = vehicle_keys(batch)
    assert len(evaluated) == 12 and len(memory) == 5 and len(phase) == 3
    assert not set(keys[evaluated]) & set(keys[memory])  # no vehicle on both sides
    assert set(phase) <= set(evaluated)
    assert len(set(keys[memory])) <= 3  # 30 % of the 10 vehicles hold the memory windows
    again = split_suite(batch, settings)
    assert all(np.array_equal(a, b) for a, b in zip((evaluated, memory, phase), again, strict=True))


def test_settings_refuse_a_memory_phase_larger_than_the_evaluation():
    with pytest.raises(ValueError, match="memory-phase-windows"):
        PaperSettings(eval_windows=5, memory_phase_windows=6)


def test_the_four_tables_run_resume_and_refuse_other_settings(tmp_path):
    evaluated, memory = _scenes(4, 1), _scenes(3, 100)
    phase = evaluated.take([0, 1])
    files = {k: save_scenarios(b, tmp_path / f"{k}.arrow")
             for k, b in (("eval", evaluated), ("memory", memory), ("memory-phase", phase))}
    data = PaperData(evaluated, memory, phase, files, MetricsConfig(), ("synthetic",))
    spec = "scripted:default"
    settings = PaperSettings(eval_windows=4, memory_windows=3, memory_phase_windows=2, memory_models=(spec,),
                             fast_models=(spec,), prompt_style="paper")
    options = PlannerOptions(llm=spec, fast_llm=spec, llm_cache=False)
    out = tmp_path / "paper"
    run = run_paper(settings, out, options, workers=1, data=data, log=lambda _: None)

    report = json.loads((out / "paper.json").read_text())
    iii = {r["row"]: r for r in report["III"]}
    assert iii["sf"]["paper"][1] == 8.9 and iii["frenet"]["paper"] is None  # the paper's CR; no paper row
    assert iii["LetsPi_F"]["letspi"]["n"] == 4 and iii["LetsPi_F"]["letspi"]["paired"]["reference"] == "sf"
    assert iii["sf"]["letspi"].get("paired") is None  # the reference itself
    phase_rows = {r["row"]: r for r in report["III_memory_phase"]}
    assert phase_rows["LetsPi_M"]["letspi"]["n"] == 2
    iv = {r["row"]: r for r in report["IV"]}
    assert list(iv) == ["w/o Ref", "w/o GA", "FS", "Base"]
    assert all(iv[r]["letspi"]["paired"]["reference"] == "Base" for r in ("w/o Ref", "w/o GA", "FS"))
    assert [r["letspi"]["n"] for r in report["V"]] == [4] * 6
    assert report["VI"][0]["letspi"]["n"] == 4
    # three collections (Base, w/o Ref, w/o GA) on the 3 memory windows, each recorded once
    assert sorted(c["scenarios"] for c in report["collections"].values()) == [3, 3, 3]
    text = (out / "paper.md").read_text()
    for heading in ("Table III", "Table IV", "Table V", "Table VI"):
        assert heading in text
    assert "8.9" in text and "reference" in text

    again = run_paper(settings, out, options, workers=1, data=data, log=lambda _: None)
    assert again.tables == run.tables  # everything was stored: the same tables, nothing collected twice
    assert json.loads((out / "paper.json").read_text())["collections"] == report["collections"]
    assert len(json.loads((out / "timing.json").read_text())["runs"]) == 2

    with pytest.raises(ValueError, match="other settings.*eval_windows"):
        run_paper(replace(settings, eval_windows=3), out, options, workers=1, data=data, log=lambda _: None)
