"""``letspi analyze headroom`` on a small scenario file: the table, the cache, the resume."""

from __future__ import annotations

import json
from pathlib import Path

from scenario_support import noisy_batch
from typer.testing import CliRunner

from letspi.cli.app import app
from letspi.scenario.store import save_scenarios

runner = CliRunner()


def test_headroom_writes_its_table_and_a_rerun_reuses_the_cached_outcomes(tmp_path: Path) -> None:
    scenarios = save_scenarios(noisy_batch(24, seed=3), tmp_path / "s.arrow")
    out = tmp_path / "hr"
    args = ["analyze", "headroom", "--scenarios", str(scenarios), "--out", str(out), "--options", "6",
            "--goals", "kinematic", "--folds", "3"]
    first = runner.invoke(app, args)
    assert first.exit_code == 0, first.output
    result = json.loads((out / "headroom.json").read_text())
    names = [r["name"] for r in result["rows"]]
    assert names[:4] == ["defaults", "best constant", "oracle, all options", "oracle, presets"]
    assert "rule: defaults unless a check fails" in names and result["n_windows"] == 24
    rows = {r["name"]: r for r in result["rows"]}
    # an oracle over more options is never worse than over fewer, nor than the defaults
    assert rows["oracle, all options"]["at_fault_pct"] <= rows["oracle, presets"]["at_fault_pct"]
    assert rows["oracle, presets"]["at_fault_pct"] <= rows["defaults"]["at_fault_pct"]
    parts = sorted((out / "random" / "parts").iterdir())
    stamp = parts[0].stat().st_mtime_ns
    again = runner.invoke(app, args)
    assert again.exit_code == 0, again.output
    assert parts[0].stat().st_mtime_ns == stamp  # reused, not recomputed
    assert (out / "headroom.md").read_text().startswith("| chooser |")


def test_decisions_pairs_a_deciding_planner_with_sf_over_two_results_directories(tmp_path: Path) -> None:
    dirs = []
    for k in range(2):
        scenarios = save_scenarios(noisy_batch(12, seed=10 + k), tmp_path / f"s{k}.arrow")
        out = tmp_path / f"ev{k}"
        res = runner.invoke(app, ["evaluate", "--scenarios", str(scenarios), "--planner", "sf", "--planner",
                                  "sf-check", "--goals", "kinematic", "--out", str(out)])
        assert res.exit_code == 0, res.output
        dirs += ["--results", str(out)]
    res = runner.invoke(app, ["analyze", "decisions", *dirs, "--planner", "sf-check", "--out", str(tmp_path / "d")])
    assert res.exit_code == 0, res.output
    report = json.loads((tmp_path / "d" / "decisions.json").read_text())["reports"][0]
    assert report["n"] == 24 and report["reference"] == "sf"
    d = report["decisions"]
    assert abs(sum(d["shares_pct"].values()) - 100.0) < 1e-9 and 0.0 <= d["consulted_pct"] <= 100.0
    f = report["CR at fault"]
    assert f["only_planner"] + f["only_reference"] + f["both"] <= 24
    rep = runner.invoke(app, ["report", str(tmp_path / "ev0")])
    assert rep.exit_code == 0, rep.output
    page = (tmp_path / "ev0" / "report.html").read_text()
    assert '<section id="decisions">' in page and "the model was consulted on" in page
    missing = runner.invoke(app, ["analyze", "decisions", *dirs, "--planner", "frenet"])
    assert missing.exit_code != 0 and "stored results of both 'frenet' and 'sf'" in " ".join(missing.output.split())
