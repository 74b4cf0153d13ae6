"""Benchmark suites: pinned digests, reserved seeds, exact McNemar power, leaderboards (intervals, paired
counts, byte-identical JSON), cached data, real HighD files checked by content."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from letspi.assembly.planners import build_planners
from letspi.benchmark.leaderboard import leaderboard, mode_board, to_json, to_markdown
from letspi.benchmark.power import alternative, mcnemar_power, windows_needed
from letspi.benchmark.suites import (
    OPEN_LOOP,
    SUITES,
    Extraction,
    GeneratedTraffic,
    Mode,
    RealHighD,
    Suite,
    get_suite,
)
from letspi.cli.app import app
from letspi.evaluation.harness import evaluate
from letspi.evaluation.results import load_planner_results
from letspi.planners.options import PlannerOptions
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.identity import scenario_digests
from letspi.scenario.provenance import SUITE_SEEDS
from letspi.scenario.types import concat_batches

#: every suite's id: a change to a definition (or to a preset or metrics default it uses) changes its
#: digest and must be made deliberately, here and in docs/benchmark.md
PINNED = {
    "highway-uniform": "highway-uniform@v2-4870b89f",
    "highway-critical": "highway-critical@v1-b272dc5d",
    "stress-closed-loop": "stress-closed-loop@v1-7ed330eb",
    "on-ramp-critical": "on-ramp-critical@v1-3e61c8cc",
    "lane-drop-critical": "lane-drop-critical@v1-df893e62",
    "highd-real": "highd-real@v1-6bdf4855",
}

runner = CliRunner()


def test_suite_digests_are_pinned() -> None:
    assert {name: s.suite_id for name, s in SUITES.items()} == PINNED


def test_suites_use_reserved_distinct_seeds_and_the_required_sizes() -> None:
    seeds = [seed for s in SUITES.values() if isinstance(s.data, GeneratedTraffic) for seed in s.data.seeds]
    assert len(seeds) == len(set(seeds)) and all(seed in SUITE_SEEDS for seed in seeds)
    for name in ("stress-closed-loop", "on-ramp-critical", "lane-drop-critical"):  # issue 28's held-out sets
        suite = SUITES[name]
        assert suite.extraction.focus == "critical" and suite.extraction.n_windows >= 2000
        closed = [m for m in suite.modes if m.mode == "closed-loop-log"]
        assert closed and closed[0].replan_s == 0.2 and closed[0].llm_period_s == 2.5
        assert (closed[0].n_windows or suite.extraction.n_windows) >= 2000
    assert SUITES["highway-uniform"].data.preset == "realistic"  # type: ignore[union-attr]
    with pytest.raises(ValueError, match="1000-1999"):
        GeneratedTraffic(preset="highd", layout="straight", seeds=(20,), minutes=1.0)


def test_any_change_to_a_definition_changes_the_digest() -> None:
    base = SUITES["highway-critical"]
    assert isinstance(base.data, GeneratedTraffic)
    variants = [
        replace(base, data=replace(base.data, overrides=(("events.cut_in_per_min", "4"),))),
        replace(base, extraction=replace(base.extraction, seed=base.extraction.seed + 1)),
        replace(base, modes=(Mode("closed-loop-log", replan_s=1.0, llm_period_s=2.5),)),
        replace(base, metrics=base.metrics.model_copy(update={"low_ttc_s": 1.5})),
    ]
    digests = {base.digest, *(v.digest for v in variants)}
    assert len(digests) == 1 + len(variants)


def test_get_suite_by_name_or_exact_id() -> None:
    suite = SUITES["stress-closed-loop"]
    assert get_suite(suite.suite_id) is suite and get_suite("stress-closed-loop") is suite
    with pytest.raises(ValueError, match="unknown benchmark suite 'nope'"):
        get_suite("nope")
    with pytest.raises(ValueError, match="not comparable"):
        get_suite("stress-closed-loop@v1-00000000")


def test_mcnemar_power_equals_a_hand_computed_value() -> None:
    # p_only_b = 0: every discordant window goes to A; the test rejects once d >= 6 (2 / 2^6 = 0.031 <= 0.05),
    # so power = P(Binomial(10, 0.3) >= 6) = 0.0473489874
    assert mcnemar_power(10, 0.3, 0.0) == pytest.approx(0.0473489874, abs=1e-9)
    assert mcnemar_power(0, 0.3, 0.0) == 0.0 and mcnemar_power(100, 0.0, 0.0) == 0.0
    # equal rates: the power is the test's size, at most alpha
    assert mcnemar_power(2000, 0.02, 0.02) <= 0.05


def test_windows_needed_is_the_smallest_size_on_its_grid() -> None:
    for discordance in (0.01, 0.03):
        n = windows_needed(discordance)
        assert n is not None
        p_a, p_b = alternative(discordance)
        assert mcnemar_power(n, p_a, p_b) >= 0.8 > mcnemar_power(n - 50, p_a, p_b)
    assert windows_needed(0.03) > windows_needed(0.01)  # type: ignore[operator]


def _batch(n: int):  # type: ignore[no-untyped-def]
    """n synthetic windows: a slower leader ahead at various gaps (some collide for cv)."""
    return concat_batches([straight_road_scenario(scenario_id=f"s{i}", neighbours=[VehicleSpec(8.0 + 3 * i, 20.0)])
                           for i in range(n)])


def test_leaderboard_counts_are_the_paired_outcomes_and_json_is_byte_identical(tmp_path: Path) -> None:
    batch = _batch(12)
    planners = build_planners(["sf", "cv", "human"], PlannerOptions(goals="kinematic"))
    evaluate(planners, batch, tmp_path)
    digests = scenario_digests(batch)
    groups = {d: f"veh{i // 3}" for i, d in enumerate(digests)}  # 3 windows per vehicle
    board = mode_board(tmp_path, ["sf", "cv", "human"], groups, "sf")
    sf, cv = load_planner_results(tmp_path, "sf"), load_planner_results(tmp_path, "cv")
    a, b = cv["collision"].to_numpy(bool), sf["collision"].to_numpy(bool)
    pair = board["paired"]["planners"]["cv"]["cr_pct"]
    assert (pair["n_only_planner"], pair["n_only_reference"], pair["n_both"]) == (
        int((a & ~b).sum()), int((b & ~a).sum()), int((a & b).sum()))
    assert pair["n_only_planner"] > 0  # the test has teeth: cv hits slow leaders sf brakes for
    assert board["planners"]["cv"]["cr_pct"] == pytest.approx(100 * a.mean())
    low, high = board["planners"]["cv"]["cr_pct_ci95"]
    assert low <= board["planners"]["cv"]["cr_pct"] <= high
    assert "sf" not in board["paired"]["planners"]
    again = mode_board(tmp_path, ["sf", "cv", "human"], groups, "sf")
    suite = SUITES["highway-critical"]
    first, second = (to_json(leaderboard(suite, {"open-loop": b}, "d")) for b in (board, again))
    assert first == second
    assert "| cv | 12 |" in to_markdown(leaderboard(suite, {"open-loop": board}, "d"))


def _tiny_suite(seed: int) -> Suite:
    return Suite(name="tiny", version=1, description="test", scripted="stress events", sizing="test",
                 data=GeneratedTraffic(preset="stress", layout="straight", seeds=(seed,), minutes=1.0,
                                       recording_minutes=1.0),
                 extraction=Extraction(focus="critical", n_windows=30, seed=1, critical_share=0.5),
                 modes=(OPEN_LOOP, Mode("closed-loop-log", replan_s=1.0, llm_period_s=2.5, llm_latency_s=1.0,
                                        n_windows=12)))


@pytest.mark.sumo
def test_run_suite_twice_gives_the_same_leaderboard_bytes_and_reuses_the_data(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("sumo")
    from letspi.benchmark.run import run_suite

    monkeypatch.setenv("LETSPI_BENCHMARK_CACHE", str(tmp_path / "cache"))
    suite = _tiny_suite(1995)
    first = run_suite(suite, ["sf", "cv"], tmp_path / "a", workers=0, reports=False, log=lambda _m: None)
    second = run_suite(suite, ["sf", "cv"], tmp_path / "b", workers=0, reports=False, log=lambda _m: None)
    assert not first.data.reused and second.data.reused and second.timing["generation_s"] == 0.0
    text = (tmp_path / "a" / "leaderboard.json").read_bytes()
    assert text == (tmp_path / "b" / "leaderboard.json").read_bytes()
    board = json.loads(text)
    assert board["suite"] == suite.suite_id and board["modes"]["closed-loop-log-1s"]["n_windows"] == 12
    assert board["modes"]["open-loop"]["n_windows"] == 30
    assert (tmp_path / "a" / "leaderboard.md").exists() and (tmp_path / "a" / "leaderboard.html").exists()
    from letspi.scenario.store import read_scenario_meta
    meta = read_scenario_meta(first.data.scenarios_file)
    assert [g["seed"] for g in meta["provenance"]["generation"]] == [1995]  # type: ignore[index]
    other = replace(suite, extraction=replace(suite.extraction, seed=2), modes=(OPEN_LOOP,))
    third = run_suite(other, ["sf"], tmp_path / "c", workers=0, reports=False, log=lambda _m: None)
    assert not third.data.reused and third.timing["generation_s"] == 0.0  # new windows, the same traffic
    assert set(first.planner_s["closed-loop-log-1s"]) == {"sf", "cv"}  # each planner's wall time per mode
    assert all(s > 0 for s in first.planner_s["closed-loop-log-1s"].values())
    # a quick try: the first 5 windows of each mode, a leaderboard that says so
    quick = run_suite(suite, ["sf"], tmp_path / "quick", workers=0, reports=False, log=lambda _m: None, limit=5)
    assert quick.data.reused and quick.board["limit"] == 5
    assert {m["n_windows"] for m in quick.board["modes"].values()} == {5}
    assert "A quick try (--limit 5)" in (tmp_path / "quick" / "leaderboard.md").read_text()
    assert "limit" not in board  # the full run's leaderboard
    said: list[str] = []  # a rerun into the same directory says what it reused
    run_suite(suite, ["sf", "cv"], tmp_path / "a", workers=0, reports=False, log=said.append)
    assert "open-loop: resumed: sf 30 of 30, cv 30 of 30 windows already stored (not planned again)" in said
    assert any(m.startswith("closed-loop-log-1s: resumed: sf 12 of 12") for m in said)


@pytest.mark.sumo
@pytest.mark.slow
def test_run_suite_in_worker_processes_gives_the_same_leaderboard(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Open-loop planners and closed-loop chunks in 2 worker processes: the leaderboard of one process."""
    pytest.importorskip("sumo")
    from letspi.benchmark.run import run_suite

    monkeypatch.setenv("LETSPI_BENCHMARK_CACHE", str(tmp_path / "cache"))
    suite = _tiny_suite(1996)
    one = run_suite(suite, ["sf", "cv", "idm"], tmp_path / "one", workers=1, reports=False, log=lambda _m: None)
    two = run_suite(suite, ["sf", "cv", "idm"], tmp_path / "two", workers=2, reports=False, log=lambda _m: None)
    assert (tmp_path / "one" / "leaderboard.json").read_bytes() == (tmp_path / "two" / "leaderboard.json").read_bytes()
    assert set(one.planner_s) == {"open-loop", "closed-loop-log-1s"}
    assert set(two.planner_s) == {"closed-loop-log-1s"}  # open-loop planners ran in the workers


@pytest.mark.sumo
def test_real_highd_suite_checks_the_files_by_content(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("sumo")
    from letspi.benchmark.data import SuiteDataError, recording_file_digest
    from letspi.benchmark.run import run_suite
    from letspi.trafficgen.generate import generate_highd

    monkeypatch.setenv("LETSPI_BENCHMARK_CACHE", str(tmp_path / "cache"))
    highd = tmp_path / "highd"
    generate_highd(highd, minutes=1.0, seed=3)  # stands in for a licensed copy
    seen = recording_file_digest(highd, 1)
    suite = Suite(name="real", version=1, description="test", scripted="real", sizing="test",
                  data=RealHighD(recording_ids=(1,), file_digests={1: "0" * 16}),
                  extraction=Extraction(focus="uniform", n_windows=20, seed=1), modes=(OPEN_LOOP,))
    with pytest.raises(SuiteDataError, match=f"recording\\(s\\) 01 differ.*{seen} vs 0000000000000000"):
        run_suite(suite, ["sf"], tmp_path / "out", highd_dir=highd, workers=0, reports=False)
    with pytest.raises(SuiteDataError, match="give its directory with --highd"):
        run_suite(suite, ["sf"], tmp_path / "out", workers=0, reports=False)
    warnings: list[str] = []
    result = run_suite(suite, ["sf"], tmp_path / "out", highd_dir=highd, allow_other_files=True, workers=0,
                       reports=False, log=warnings.append)
    assert any(w.startswith("warning:") for w in warnings)
    assert result.board["highd_files_seen"] == {"01": seen}
    pinned = replace(suite, data=RealHighD(recording_ids=(1,), file_digests={1: seen}))
    assert run_suite(pinned, ["sf"], tmp_path / "out2", highd_dir=highd, workers=0, reports=False,
                     log=lambda _m: None).board["modes"]["open-loop"]["n_windows"] == 20


def test_cli_list_show_and_power() -> None:
    listed = runner.invoke(app, ["benchmark", "list"])
    assert listed.exit_code == 0 and all(suite_id in listed.output for suite_id in PINNED.values())
    shown = runner.invoke(app, ["benchmark", "show", "lane-drop-critical", "--json"])
    assert shown.exit_code == 0 and json.loads(shown.output)["id"] == PINNED["lane-drop-critical"]
    power = runner.invoke(app, ["benchmark", "power", "--discordance-pct", "1"])
    assert power.exit_code == 0 and f"| {windows_needed(0.01)} |" in power.output
    bad = runner.invoke(app, ["benchmark", "run", "nope"])
    assert bad.exit_code == 2 and "unknown benchmark suite" in bad.output
    assert np.isfinite(mcnemar_power(3000, *alternative(0.035)))
