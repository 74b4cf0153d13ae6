"""The command line: commands run, print what they promise and fail with clear messages."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from letspi.cli.app import app
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.store import save_scenarios
from letspi.scenario.types import SCHEMA_VERSION, concat_batches

runner = CliRunner()


def _scenario_file(tmp_path):
    batch = concat_batches([
        straight_road_scenario(scenario_id=f"s{i}", neighbours=[VehicleSpec(25.0, 27.0)])
        for i in range(4)
    ])
    return save_scenarios(batch, tmp_path / "s.arrow")


def test_evaluate_prints_the_table_and_writes_files(tmp_path):
    path = _scenario_file(tmp_path)
    out = tmp_path / "ev"
    result = runner.invoke(app, ["evaluate", "--scenarios", str(path), "--planner", "human",
                                 "--planner", "sf", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "| human |" in result.output and "| sf |" in result.output
    metrics = json.loads((out / "metrics.json").read_text())["planners"]
    assert metrics["sf"]["n"] == 4


def test_evaluate_unknown_planner_is_a_clear_error(tmp_path):
    path = _scenario_file(tmp_path)
    result = runner.invoke(app, ["evaluate", "--scenarios", str(path), "--planner", "magic", "--out",
                                 str(tmp_path / "ev")])
    assert result.exit_code == 2
    assert "unknown planner 'magic'" in result.output


def test_scenarios_missing_directory_names_it(tmp_path):
    result = runner.invoke(app, ["data", "scenarios", "--highd", str(tmp_path / "nowhere"), "--out",
                                 str(tmp_path / "s.arrow")])
    assert result.exit_code == 2
    assert "nowhere" in result.output


def test_info_json(tmp_path):
    path = _scenario_file(tmp_path)
    result = runner.invoke(app, ["data", "info", str(path), "--json"])
    assert result.exit_code == 0, result.output
    info = json.loads(result.output)
    assert info["n_scenarios"] == 4 and info["schema_version"] == SCHEMA_VERSION


def test_plan_json_shows_parameters_rationale_and_iterations(tmp_path):
    path = _scenario_file(tmp_path)
    result = runner.invoke(app, ["plan", "--scenarios", str(path), "--index", "1", "--planner", "letspi-memory",
                                 "--llm", "scripted:default", "--json", "--show-prompt"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    assert out["scenario_id"] == "s1" and out["planner"].startswith("letspi-memory")
    assert set(out["info"]) >= {"tau_s", "k_np", "lon_factor", "llm_latency_s", "fallback", "validated"}
    assert out["iterations"][0]["prompt"].startswith("[system]") and "safety_report" in out["iterations"][0]
    assert len(out["trajectory"]["every_1s_xy_m"]) == 5 and "min_ttc_s" in out["metrics"]


def test_collect_then_fast_plan_shows_retrieved_memories(tmp_path):
    path = _scenario_file(tmp_path)
    mem = tmp_path / "m.sqlite"
    args = ["collect", "--scenarios", str(path), "--memory", str(mem), "--llm", "scripted:default", "--no-cache"]
    first = runner.invoke(app, args)
    assert first.exit_code == 0, first.output
    assert "4 new experiences" in " ".join(first.output.split())
    again = " ".join(runner.invoke(app, args).output.split())  # rich wraps lines at the terminal width
    assert "0 new experiences" in again and "4 already stored" in again
    result = runner.invoke(app, ["plan", "--scenarios", str(path), "--index", "0", "--planner", "letspi-fast",
                                 "--fast-llm", "scripted:default", "--memory", str(mem), "--json"])
    assert result.exit_code == 0, result.output
    # every scenario of the file is the same vehicle (ego 1 of one recording): retrieval leaves them out
    assert json.loads(result.output)["retrieved_memories"] == []


def test_fast_planner_without_memory_is_a_clear_error(tmp_path):
    path = _scenario_file(tmp_path)
    result = runner.invoke(app, ["plan", "--scenarios", str(path), "--index", "0", "--planner", "letspi-fast"])
    assert result.exit_code == 2 and "need a memory bank: --memory FILE" in result.output


def test_prompt_shows_both_prompts_and_the_fast_one_is_shorter(tmp_path):
    path = _scenario_file(tmp_path)
    physics = runner.invoke(app, ["prompt", "--scenarios", str(path), "--index", "0", "--goals", "kinematic"])
    fast = runner.invoke(app, ["prompt", "--scenarios", str(path), "--index", "0", "--goals", "kinematic", "--fast"])
    assert physics.exit_code == 0 and fast.exit_code == 0, physics.output + fast.output
    assert physics.output.startswith("[system]") and "[user]" in physics.output
    assert "k_np" in physics.output and "k_np" in fast.output
    assert len(fast.output) < 0.7 * len(physics.output)
