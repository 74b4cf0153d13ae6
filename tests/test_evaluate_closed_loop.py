"""``letspi evaluate --mode closed-loop-*``: the harness's layout, keys and resume with SUMO's simulation.

The engine itself is tested in test_simulation_*.py; these tests go through the CLI and the harness.
"""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from test_simulation_support import BrakePlanner, generated_batch
from typer.testing import CliRunner

from letspi.assembly.planners import BuiltPlanner
from letspi.cli.app import app
from letspi.evaluation.closed_loop import (
    ClosedLoopSetupError,
    check_setup,
    closed_loop_rows,
    evaluate_closed_loop,
)
from letspi.evaluation.harness import EvaluationSettings, evaluate
from letspi.evaluation.results import EvaluationDirError, load_planner_results
from letspi.metrics.config import MetricsConfig
from letspi.planners.cv import CvConfig
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.store import load_scenarios, save_scenarios
from letspi.scenario.types import ScenarioBatch, concat_batches
from letspi.simulation.config import ClosedLoopConfig
from letspi.viz.compare import compare_dirs

pytestmark = pytest.mark.sumo
runner = CliRunner()
LOG, REACTIVE, HYBRID = "closed-loop-log", "closed-loop-reactive", "closed-loop-hybrid"


@pytest.fixture(scope="module")
def traffic_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """16 scenarios of generated traffic (both directions)."""
    d = tmp_path_factory.mktemp("cl_eval")
    return save_scenarios(generated_batch(d / "gen", n=16, seed=5), d / "traffic.arrow")


def _evaluate(*args: str) -> tuple[int, str]:
    result = runner.invoke(app, ["evaluate", *args])
    return result.exit_code, result.output


def _metrics(out: Path) -> dict[str, dict[str, float]]:
    return json.loads((out / "metrics.json").read_text())["planners"]


def test_human_in_closed_loop_log_reproduces_its_open_loop_metrics(tmp_path: Path, traffic_file: Path) -> None:
    code, text = _evaluate("--scenarios", str(traffic_file), "--planner", "human", "--out", str(tmp_path / "open"))
    assert code == 0, text
    code, text = _evaluate("--scenarios", str(traffic_file), "--planner", "human", "--out", str(tmp_path / "log"),
                           "--mode", LOG)
    assert code == 0, text
    assert "Mode: closed-loop-log (log replay), replanning every 1 s (human)" in text and "| human |" in text
    open_m, log_m = _metrics(tmp_path / "open")["human"], _metrics(tmp_path / "log")["human"]
    assert log_m["n"] == open_m["n"] == 16
    assert log_m["cr_pct"] == 0.0 and "sumo_cr_pct" not in log_m  # the replay runs no SUMO
    assert log_m["ade_m"] <= 0.1 and log_m["fde_m"] <= 0.1
    assert log_m["replans_per_scenario"] == 5.0
    for key in ("ttc_s", "lt_pct", "sr_pct", "min_box_gap_m", "cr_at_fault_pct"):
        assert log_m[key] == pytest.approx(open_m[key], abs=0.05), key
    # rows keyed by scenario digest, in dataset order, one per scenario; the plan columns hold the simulated ego
    rows_open = load_planner_results(tmp_path / "open", "human")
    rows_log = load_planner_results(tmp_path / "log", "human", with_plans=True)
    assert list(rows_log["scenario_digest"]) == list(rows_open["scenario_digest"])
    assert "cl_plan_xy_m" not in load_planner_results(tmp_path / "log", "human")  # big columns only on request
    panel = closed_loop_rows(tmp_path / "log", "human")
    row = panel[str(rows_log["scenario_digest"][0])]
    assert row.plans_xy_m.shape == (5, 125, 2) and list(row.replan_step) == [0, 25, 50, 75, 100]
    assert row.nbr_valid.shape == row.nbr_xy_m.shape[:2]
    np.testing.assert_allclose(row.ego_xy_m, np.asarray(rows_log["plan_xy_m"][0]).reshape(125, 2), atol=1e-4)


def _brake_batch() -> ScenarioBatch:
    """Ego at 30 m/s, a follower 25 m behind at the same speed (0.83 s), a car in the next lane."""
    follower = VehicleSpec(x0_m=-(25.0 + 4.5), speed_mps=30.0)
    side = VehicleSpec(x0_m=15.0, speed_mps=31.0, lane_offset=1)
    return concat_batches([straight_road_scenario(ego_speed_mps=30.0, neighbours=[follower, side],
                                                  scenario_id=f"brake{i}") for i in range(2)])


def test_a_hard_braking_ego_collides_in_log_mode_and_not_in_reactive_mode(tmp_path: Path) -> None:
    batch = _brake_batch()
    built = BuiltPlanner("brake", CvConfig(), BrakePlanner(8.0))
    log = evaluate_closed_loop([built], batch, tmp_path / "log", ClosedLoopConfig(LOG, simulator="sumo"))["brake"]
    reactive = evaluate_closed_loop([built], batch, tmp_path / "reactive", ClosedLoopConfig(REACTIVE))["brake"]
    assert log["cr_pct"] == 100.0 and log["sumo_cr_pct"] == 100.0 and log["cr_rear_pct"] == 100.0
    assert reactive["cr_pct"] == 0.0 and reactive["sumo_cr_pct"] == 0.0
    # the reactive follower braked: its simulated path is stored for the panel
    row = next(iter(closed_loop_rows(tmp_path / "reactive", "brake").values()))
    assert row.nbr_xy_m[0, -1, 0] < 30.0 * 5.0 - 29.5
    run = json.loads((tmp_path / "reactive" / "run.json").read_text())["identity"]
    assert run["mode"] == REACTIVE and run["mode_settings"]["driver"]["decel_mps2"] == 3.0
    assert "driver" not in json.loads((tmp_path / "log" / "run.json").read_text())["identity"]["mode_settings"]


def test_modes_and_periods_are_never_mixed_in_one_directory(tmp_path: Path, traffic_file: Path) -> None:
    out = tmp_path / "ev"
    base = ["--scenarios", str(traffic_file), "--limit", "4", "--out", str(out)]
    code, text = _evaluate(*base, "--planner", "cv")
    assert code == 0, text
    code, text = _evaluate(*base, "--planner", "cv", "--mode", LOG)
    assert code == 2 and "mode: open-loop -> closed-loop-log" in " ".join(text.split())
    out2 = tmp_path / "ev2"
    base2 = ["--scenarios", str(traffic_file), "--limit", "4", "--out", str(out2), "--mode", LOG]
    code, text = _evaluate(*base2, "--planner", "cv", "--planner", "cv5=cv", "--replan-s", "cv5=5")
    assert code == 0, text
    assert "replanning every 1 s (cv), 5 s (cv5)" in text
    m = _metrics(out2)
    assert m["cv"]["replans_per_scenario"] == 5.0 and m["cv5"]["replans_per_scenario"] == 1.0
    cfg = json.loads((out2 / "per_scenario" / "cv5" / "config.json").read_text())
    assert cfg["evaluation"] == {"mode": LOG, "replan_s": 5.0} and cfg["identity"]["evaluation"]["replan_s"] == 5.0
    assert cfg["key"] != json.loads((out2 / "per_scenario" / "cv" / "config.json").read_text())["key"]
    code, text = _evaluate(*base2, "--planner", "cv", "--replan-s", "2")
    assert code == 2 and "evaluation.replan_s: 1.0 -> 2.0" in " ".join(text.split())
    # rerunning the same command resumes: nothing new, same rows
    before = load_planner_results(out2, "cv")
    code, text = _evaluate(*base2, "--planner", "cv")
    assert code == 0, text
    pd.testing.assert_frame_equal(load_planner_results(out2, "cv"), before)
    with pytest.raises(EvaluationDirError, match="mode: closed-loop-log -> closed-loop-reactive"):
        evaluate_closed_loop([BuiltPlanner("cv", CvConfig(), BrakePlanner())],
                             load_scenarios(traffic_file, np.arange(4)), out2, ClosedLoopConfig(REACTIVE))


def test_hybrid_mode_records_its_settings_and_refuses_other_ones(tmp_path: Path, traffic_file: Path) -> None:
    out = tmp_path / "hy"
    base = ["--scenarios", str(traffic_file), "--limit", "4", "--planner", "cv", "--out", str(out)]
    code, text = _evaluate(*base, "--mode", HYBRID)
    assert code == 0, text
    assert "scripted events: none" in " ".join(text.split())  # the file has no provenance to find events by
    settings = json.loads((out / "run.json").read_text())["identity"]["mode_settings"]
    assert settings["handover"] == {"lanes": 0, "behind_m": 0.0, "follow_log_speed": True}
    assert settings["scripted"] == {"n": 0, "digest": "none"} and settings["driver"]["decel_mps2"] == 3.0
    m = _metrics(out)["cv"]
    assert m["n"] == 4 and m["nbr_reactive_per_scenario"] >= 0.0
    code, text = _evaluate(*base, "--mode", HYBRID, "--handover-lanes", "1")
    assert code == 2 and "mode_settings.handover.lanes: 0 -> 1" in " ".join(text.split()), text


def test_closed_loop_options_are_checked_with_one_clear_line(tmp_path: Path, traffic_file: Path,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    base = ["--scenarios", str(traffic_file), "--limit", "2", "--out", str(tmp_path / "ev"), "--planner", "cv"]
    cases = [
        (["--replan-s", "2"], "--replan-s apply to the closed-loop modes only"),
        (["--workers", "2"], "--workers apply to the closed-loop modes only"),
        (["--mode", "closed-loop"], "unknown evaluation mode 'closed-loop'; did you mean closed-loop-log"),
        (["--mode", LOG, "--replan-s", "sf=2"], "no planner labelled 'sf'"),
        (["--mode", LOG, "--replan-s", "0"], "replan_s must be between one frame"),
        (["--mode", LOG, "--replan-s", "fast"], "--replan-s takes S or LABEL=S"),
        (["--mode", LOG, "--concurrency", "4"], "--concurrency applies to open loop"),
        (["--mode", LOG, "--events", "none"], "--events applies to --mode closed-loop-hybrid only"),
        (["--mode", REACTIVE, "--handover-lanes", "1"], "--handover-lanes applies to --mode closed-loop-hybrid"),
        (["--mode", HYBRID, "--events", str(tmp_path / "nowhere")], "not a directory"),
        (["--llm-period-s", "2"], "--llm-period-s apply to the closed-loop modes only"),
        (["--llm-latency-s", "0"], "--llm-latency-s apply to the closed-loop modes only"),
        (["--mode", LOG, "--llm-latency-s", "-1"], "--llm-latency-s must be >= 0 seconds"),
        (["--mode", LOG, "--llm-period-s", "0"], "--llm-period-s must be a positive number of seconds"),
    ]
    for extra, message in cases:
        code, text = _evaluate(*base, *extra)
        assert code == 2, (extra, text)
        assert message in " ".join(text.split()), (extra, text)
        assert "Traceback" not in text
    assert not (tmp_path / "ev").exists()
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    code, text = _evaluate(*base, "--mode", LOG, "--sumo-gui")
    assert code == 2 and ("needs a display" in text or "needs SUMO's sumo-gui" in text), text
    with pytest.raises(ClosedLoopSetupError, match="drop --workers"):
        check_setup(ClosedLoopConfig(LOG, workers=2, sumo_gui=True))
    if importlib.util.find_spec("ray") is None:
        code, text = _evaluate(*base, "--mode", LOG, "--ray")
        assert code == 2 and "pip install 'letspi[ray]'" in text


RUN_SCRIPT = """
import sys
from letspi.cli.app import app
sys.argv = ["letspi", "evaluate", "--scenarios", sys.argv[1], "--out", sys.argv[2], "--planner", "idm",
            "--mode", "closed-loop-reactive", "--workers", "2", "--chunk-size", "2"]
if __name__ == "__main__":
    app()
"""


def _workers_of(pid: int) -> list[int]:
    path = Path(f"/proc/{pid}/task/{pid}/children")
    children = [int(c) for c in path.read_text().split()] if path.exists() else []
    return [c for c in children if b"spawn_main" in Path(f"/proc/{c}/cmdline").read_bytes()
            and b"resource_tracker" not in Path(f"/proc/{c}/cmdline").read_bytes()]


def _parts(out: Path) -> int:
    d = out / "per_scenario" / "idm"
    return len(list(d.glob("part-*.parquet"))) if d.exists() else 0


def _wait(out: Path, proc: subprocess.Popen[str], n: int, timeout_s: float = 180.0) -> None:
    t0 = time.monotonic()
    while _parts(out) < n:
        if proc.poll() is not None:
            raise AssertionError(f"run ended early: {proc.stderr.read() if proc.stderr else ''}")
        if time.monotonic() - t0 > timeout_s:
            raise AssertionError("no part written in time")
        time.sleep(0.02)


@pytest.mark.slow
def test_a_killed_worker_and_a_killed_run_resume_without_duplicates(tmp_path: Path, traffic_file: Path) -> None:
    out = tmp_path / "ev"
    script = tmp_path / "run.py"
    script.write_text(RUN_SCRIPT)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    proc = subprocess.Popen([sys.executable, str(script), str(traffic_file), str(out)], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    try:
        _wait(out, proc, 1)
        workers = _workers_of(proc.pid)
        assert len(workers) == 2
        os.kill(workers[0], signal.SIGKILL)  # the pool replaces it and simulates its chunk again
        _wait(out, proc, 3)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # then the whole run, mid-run
        proc.wait(timeout=30)
    before = load_planner_results(out, "idm")
    assert 6 <= len(before) < 16 and before["scenario_digest"].is_unique
    code, text = _evaluate("--scenarios", str(traffic_file), "--out", str(out), "--planner", "idm",
                           "--mode", REACTIVE, "--workers", "2", "--chunk-size", "2")
    assert code == 0, text
    after = load_planner_results(out, "idm")
    assert len(after) == 16 and after["scenario_digest"].is_unique and list(after["row"]) == list(range(16))
    kept = after.set_index("scenario_digest").loc[before["scenario_digest"], "min_ttc_s"].to_numpy()
    np.testing.assert_array_equal(kept, before["min_ttc_s"].to_numpy())
    assert _metrics(out)["idm"]["n"] == 16


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("ray") is None,
                    reason="ray is not installed (optional extra: pip install 'letspi[ray]')")
def test_ray_path_gives_the_in_process_rows(tmp_path: Path, traffic_file: Path) -> None:
    import ray

    base = ["--scenarios", str(traffic_file), "--limit", "8", "--planner", "idm", "--mode", REACTIVE,
            "--chunk-size", "4"]
    code, text = _evaluate(*base, "--out", str(tmp_path / "local"))
    assert code == 0, text
    try:
        code, text = _evaluate(*base, "--out", str(tmp_path / "ray"), "--ray", "--workers", "2")
        assert code == 0, text
    finally:
        ray.shutdown()
    local, on_ray = load_planner_results(tmp_path / "local", "idm"), load_planner_results(tmp_path / "ray", "idm")
    assert len(on_ray) == 8 and list(on_ray["scenario_digest"]) == list(local["scenario_digest"])
    np.testing.assert_allclose(on_ray["min_box_gap_m"], local["min_box_gap_m"], atol=1e-6)
    assert (json.loads((tmp_path / "ray" / "per_scenario" / "idm" / "config.json").read_text())["key"]
            == json.loads((tmp_path / "local" / "per_scenario" / "idm" / "config.json").read_text())["key"])


def test_compare_report_and_plot_show_open_and_closed_loop_side_by_side(tmp_path: Path, traffic_file: Path) -> None:
    batch = _brake_batch()
    scen = save_scenarios(batch, tmp_path / "brake.arrow")
    built = BuiltPlanner("brake", CvConfig(), BrakePlanner(8.0))
    evaluate([built], batch, tmp_path / "open", EvaluationSettings(scenarios_file=str(scen)))
    evaluate_closed_loop([built], batch, tmp_path / "reactive", ClosedLoopConfig(REACTIVE), scenarios_file=str(scen))
    result = runner.invoke(app, ["compare", str(tmp_path / "open"), str(tmp_path / "reactive"), "--out",
                                 str(tmp_path / "cmp")])
    assert result.exit_code == 0, result.output
    assert "A = " in result.output and "(open-loop)" in result.output and "(closed-loop-reactive)" in result.output
    # both collide in open loop only: 2 discordant windows, Δ −100 points, McNemar p = 2 / 2² = 0.5
    assert "| brake | ↓ CR % | 2 | 100.00 (34.24–100.00) | 0.00 (0.00–65.76) | -100.00" in result.output
    assert "| 2 | 0 | 0 | 0.500 |" in result.output
    data = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert len(data["collides_only_a"]["brake"]) == 2 and data["collides_only_b"]["brake"] == []
    cr = data["paired"]["planners"]["brake"]["cr_pct"]
    assert (cr["n_only_reference"], cr["n_only_planner"], cr["p_mcnemar"], cr["diff"]) == (2, 0, 0.5, -100.0)
    page = (tmp_path / "cmp" / "compare.html").read_text()
    assert page.count("<img src='data:image/png;base64,") == 2 and "collides with brake (A) only" in page
    # the report of a closed-loop directory draws the panel for its worst scenarios
    code = runner.invoke(app, ["report", str(tmp_path / "reactive")]).exit_code
    assert code == 0
    report = (tmp_path / "reactive" / "report.html").read_text()
    assert report.count("data:image/png;base64,") >= 3  # distributions + 2 worst scenarios
    assert "mode <strong>closed-loop-reactive</strong>" in report
    # a directory of a subset is compared on the windows both hold; one of other scenarios is refused
    subset = tmp_path / "subset"
    evaluate([built], batch.take(np.array([0])), subset)
    assert compare_dirs(tmp_path / "open", subset).n_common == {"brake": 1}
    other = tmp_path / "other"
    evaluate([built], concat_batches([straight_road_scenario(ego_speed_mps=25.0, scenario_id="other")]), other)
    result = runner.invoke(app, ["compare", str(tmp_path / "open"), str(other)])
    assert result.exit_code == 2 and "share no scenario" in result.output
    # and so are other metrics configurations, or other planners in another mode
    strict = tmp_path / "strict"
    evaluate([built], batch, strict, EvaluationSettings(metrics=MetricsConfig(low_ttc_s=3.0)))
    result = runner.invoke(app, ["compare", str(tmp_path / "open"), str(strict)])
    assert result.exit_code == 2 and "different metrics configurations" in result.output
    result = runner.invoke(app, ["compare", str(tmp_path / "open"), str(tmp_path / "reactive"), "--reference", "brake"])
    assert result.exit_code == 2 and "same mode" in result.output
    # letspi plot --mode simulates one scenario and draws the panel
    result = runner.invoke(app, ["plot", "--scenarios", str(traffic_file), "--index", "1", "--planner", "cv",
                                 "--mode", LOG, "--out", str(tmp_path / "p.png")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "p.png").stat().st_size > 10_000


def test_llm_planners_run_dual_rate_with_their_period_and_fixed_latency_in_the_key(tmp_path: Path,
                                                                                   traffic_file: Path) -> None:
    out = tmp_path / "ev"
    base = ["--scenarios", str(traffic_file), "--limit", "2", "--llm", "scripted:default", "--no-cache", "--out",
            str(out), "--mode", LOG, "--replan-s", "0.2", "--llm-period-s", "2.5"]
    code, text = _evaluate(*base, "--planner", "llm", "--planner", "cv", "--llm-latency-s", "0.4")
    assert code == 0, text
    assert "LLM planners ask their model every 2.5 s, answers in force after 0.4 s" in " ".join(text.split())
    m = _metrics(out)["llm"]
    assert m["replans_per_scenario"] == 25.0  # the physics every 0.2 s
    assert m["llm_calls_per_scenario"] == 2.0 and m["inference_n"] == 2  # the model at t = 0 and 2.6 s
    assert m["llm_in_force_pct"] == pytest.approx(100.0 * 23 / 25)  # the fitted parameters for the first 0.4 s
    assert 0.4 <= m["llm_params_age_s"] < 2.8 and m["planner_cpu_ms_per_replan"] > 0
    assert _metrics(out)["cv"]["planner_cpu_ms_per_replan"] > 0 and "llm_params_age_s" not in _metrics(out)["cv"]
    cfg = json.loads((out / "per_scenario" / "llm" / "config.json").read_text())
    assert cfg["evaluation"] == {"mode": LOG, "replan_s": 0.2,
                                 "dual_rate": {"llm_period_s": 2.5, "llm_latency_s": 0.4}}
    assert "dual_rate" not in json.loads((out / "per_scenario" / "cv" / "config.json").read_text())["evaluation"]
    code, text = _evaluate(*base, "--planner", "llm", "--llm-latency-s", "1")  # another latency, another key
    assert code == 2 and "llm_latency_s" in text, text
