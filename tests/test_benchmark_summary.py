"""letspi benchmark summary: one table over several leaderboards (cells, order, dominance, errors)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from letspi.benchmark.summary import dominated_by, load_boards, summary_markdown
from letspi.cli.app import app


def _row(cr_fault: float, ci: tuple[float, float], sr: float, sr_ci: tuple[float, float]) -> dict:
    return {"cr_at_fault_pct": cr_fault, "cr_at_fault_pct_ci95": list(ci), "sr_pct": sr, "sr_pct_ci95": list(sr_ci)}


def _board(name: str) -> dict:
    planners = {"human": _row(0.0, (0.0, 0.1), 99.0, (98.0, 99.5)),
                "sf": _row(5.0, (4.0, 6.2), 60.0, (58.0, 62.0)),
                "a": _row(2.0, (1.5, 2.6), 70.0, (68.0, 72.0)),   # apart on both: dominates sf
                "b": _row(4.5, (3.5, 5.5), 70.0, (68.0, 72.0))}   # CR intervals overlap sf's: does not
    paired = {k: {"cr_at_fault_pct": {"p_mcnemar": 0.0123}} for k in ("a", "b", "human")}
    mode = {"n_windows": 100, "planners": planners, "paired": {"reference": "sf", "planners": paired}}
    return {"suite": f"{name}@v1-0000", "definition": {"name": name},
            "modes": {"closed-loop-log-0.2s": dict(mode), "open-loop": dict(mode)}}


def test_dominance_needs_both_intervals_apart() -> None:
    mode = _board("x")["modes"]["open-loop"]
    assert dominated_by(mode, "sf") == ["a"]
    assert dominated_by(mode, "a") == []
    assert dominated_by(mode, "missing") == []


def test_table_cells_order_and_dominance_line() -> None:
    text = summary_markdown([_board("s1"), _board("s2")], ["sf", "a", "c"])
    lines = text.splitlines()
    assert lines[0] == ("| planner | s1 open-loop (n 100) | s1 closed-loop-log-0.2s (n 100) | s2 open-loop (n 100) "
                        "| s2 closed-loop-log-0.2s (n 100) |")
    assert lines[2].startswith("| sf | 5.00 (4.00–6.20) · 60.0 |")  # the reference: no p
    assert lines[3].startswith("| a | 2.00 (1.50–2.60) p 0.012 · 70.0 |")
    assert lines[4] == "| c | – | – | – | – |"
    assert "sf is dominated on s1 open-loop by a" in text
    assert "b is dominated" not in text
    text = summary_markdown([_board("s1"), _board("s2")], ["sf"], ["open-loop"])
    assert text.splitlines()[0] == "| planner | s1 (n 100) | s2 (n 100) |"
    with pytest.raises(ValueError, match="no leaderboard has a mode closed"):
        summary_markdown([_board("s1")], None, ["closed"])


def test_cli_reads_leaderboards_and_names_a_missing_one(tmp_path: Path) -> None:
    for name in ("s1", "s2"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "leaderboard.json").write_text(json.dumps(_board(name)))
    runner = CliRunner()
    result = runner.invoke(app, ["benchmark", "summary", str(tmp_path / "s1"), str(tmp_path / "s2"),
                                 "--planner", "sf", "--planner", "a"])
    assert result.exit_code == 0, result.output
    assert "| a | 2.00 (1.50–2.60) p 0.012 · 70.0 |" in result.output
    result = runner.invoke(app, ["benchmark", "summary", str(tmp_path / "nothing")])
    assert result.exit_code == 2
    assert "no leaderboard here" in " ".join(result.output.split())
    with pytest.raises(ValueError, match="no leaderboard here"):
        load_boards([tmp_path])


def test_runs_of_one_suite_share_a_column() -> None:
    base, extra = _board("s1"), _board("s1")
    for mode in extra["modes"].values():
        mode["planners"] = {"sf": mode["planners"]["sf"], "llm": _row(1.0, (0.5, 1.8), 61.0, (59.0, 63.0))}
        mode["paired"] = {"reference": "sf", "planners": {"llm": {"cr_at_fault_pct": {"p_mcnemar": 0.5}}}}
    text = summary_markdown([base, extra], ["a", "llm"])
    assert text.splitlines()[0].count("s1 open-loop") == 1
    assert "| llm | 1.00 (0.50–1.80) p 0.5 · 61.0 |" in text
    extra["modes"]["open-loop"]["n_windows"] = 50
    with pytest.raises(ValueError, match="different windows"):
        summary_markdown([base, extra])


def test_run_refuses_an_unknown_mode_before_any_work(tmp_path: Path) -> None:
    from letspi.benchmark.run import selected_modes
    from letspi.benchmark.suites import get_suite

    suite = get_suite("stress-closed-loop")
    assert [m.slug for m in selected_modes(suite, ["closed-loop-log-0.2s"])] == ["closed-loop-log-0.2s"]
    assert [m.slug for m in selected_modes(suite, None)] == ["open-loop", "closed-loop-log-0.2s"]
    result = CliRunner().invoke(app, ["benchmark", "run", "stress-closed-loop", "--mode", "closed-loop",
                                      "--out", str(tmp_path / "out")])
    assert result.exit_code == 2
    assert ("has no mode closed-loop; did you mean closed-loop-log-0.2s or open-loop? (its modes: open-loop, "
            "closed-loop-log-0.2s)") in " ".join(result.output.split())
    assert not (tmp_path / "out").exists()


def test_run_passes_release_to_the_closed_loop_modes_and_refuses_it_in_open_loop_only(tmp_path: Path) -> None:
    from letspi.benchmark.run import closed_loop_settings, selected_modes
    from letspi.benchmark.suites import get_suite

    suite = get_suite("stress-closed-loop")
    (closed,) = selected_modes(suite, ["closed-loop-log-0.2s"])
    assert closed_loop_settings(closed, 2).dual_rate.release == "checks"
    assert closed_loop_settings(closed, 2, "prediction").dual_rate.identity()["release"] == "prediction"
    with pytest.raises(ValueError, match="--release must be one of checks, prediction, off"):
        closed_loop_settings(closed, 2, "never")
    result = CliRunner().invoke(app, ["benchmark", "run", "stress-closed-loop", "--mode", "open-loop", "--release",
                                      "off", "--planner", "sf", "--out", str(tmp_path / "out")])
    assert result.exit_code == 2
    assert "--release off applies to the closed-loop modes only; the modes run here: open-loop" in " ".join(
        result.output.split())
    assert not (tmp_path / "out").exists()
