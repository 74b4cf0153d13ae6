"""Intervals and paired comparisons in evaluation outputs: metrics.json, metrics.md, the CLI,
``letspi compare`` (issue 27 items 1 and 2)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from test_simulation_support import BrakePlanner
from typer.testing import CliRunner

from letspi.assembly.planners import BuiltPlanner, build_planners
from letspi.cli.app import app
from letspi.evaluation.harness import EvaluationSettings, evaluate
from letspi.evaluation.results import load_planner_results, stored_vehicles
from letspi.metrics.config import MetricsConfig
from letspi.metrics.stats import (
    bootstrap_mean_interval,
    design_effect,
    mcnemar_exact,
    vehicle_wilson_interval,
    wilson_ends,
)
from letspi.planners.cv import CvConfig
from letspi.planners.options import PlannerOptions
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.split import vehicle_keys
from letspi.scenario.store import save_scenarios
from letspi.scenario.types import ScenarioBatch, concat_batches
from letspi.viz.compare import compare_dirs

runner = CliRunner()


def _batch() -> ScenarioBatch:
    """16 windows of 5 ego vehicles (1-5 windows each); a close follower in every third window, so a
    hard-braking ego is run into there, and leaders at varied gaps."""
    rows = []
    for i in range(16):
        neighbours = [VehicleSpec(15.0 + 3.0 * i, 26.0 + 0.5 * (i % 5))]
        if i % 3 == 0:
            neighbours.append(VehicleSpec(-(12.0 + 4.5), 30.0))
        rows.append(straight_road_scenario(scenario_id=f"s{i}", neighbours=neighbours))
    batch = concat_batches(rows)
    ego = np.array([1, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 4, 4, 5, 5], dtype=batch.ego_id.dtype)
    return dataclasses.replace(batch, ego_id=ego)


def _planners() -> list[BuiltPlanner]:
    return [*build_planners(["sf", "cv"], PlannerOptions(goals="kinematic")),
            BuiltPlanner("brake", CvConfig(), BrakePlanner(8.0))]


def _without_timing(entry: dict[str, Any]) -> dict[str, Any]:
    return {name: {k: v for k, v in keys.items() if not k.startswith("inference")} for name, keys in entry.items()}


def test_metrics_json_has_an_interval_for_every_rate_and_mean_and_pairs_with_sf(tmp_path: Path) -> None:
    batch = _batch()
    evaluate(_planners(), batch, tmp_path, EvaluationSettings(scenarios_file="mem"))
    summary = json.loads((tmp_path / "metrics.json").read_text())
    methods = summary["statistics"]["interval_methods"]
    assert methods["cr_pct"] == "vehicle-wilson" and methods["ttc_s"] == "vehicle-bootstrap"
    assert methods["pet_s"] == "vehicle-bootstrap" and "ttc_finite_n" not in methods  # counts carry none
    assert summary["statistics"]["n_vehicles"] == {"sf": 5, "cv": 5, "brake": 5}
    for name, agg in summary["planners"].items():
        own = summary["intervals"][name]
        assert set(own) == set(methods) - {"sumo_cr_pct", "fallback_pct", "shielded_pct"}
        for key, interval in own.items():
            if interval is not None and isinstance(agg[key], float):  # ends carry 6 significant digits
                slack = 1e-5 * abs(agg[key]) + 1e-12
                assert interval[0] - slack <= agg[key] <= interval[1] + slack, (name, key)
    frames = {name: load_planner_results(tmp_path, name) for name in ("sf", "brake")}
    groups = vehicle_keys(batch)[frames["brake"]["row"]]
    # the brake planner is run into from behind in every third window: CR 6 of 16, Wilson
    hit = frames["brake"]["collision"].to_numpy(dtype=bool)
    assert hit.sum() == 6 and summary["planners"]["brake"]["cr_pct"] == pytest.approx(100 * 6 / 16)
    low, high = vehicle_wilson_interval(hit, groups)  # Wilson with 16 windows / design effect of 5 vehicles
    assert summary["intervals"]["brake"]["cr_pct"] == pytest.approx([100 * low, 100 * high], rel=1e-5)
    deff = summary["statistics"]["design_effects"]["brake"]["cr_pct"]
    assert deff == pytest.approx(design_effect(hit, groups), abs=1e-3)
    assert (low, high) == wilson_ends(6 / 16, 16 / design_effect(hit, groups))
    # TTC: the vehicle bootstrap of the capped per-window TTC, the point value's own definition
    capped = np.fmin(frames["brake"]["min_ttc_s"].to_numpy(), MetricsConfig().ttc_cap_s)
    assert summary["intervals"]["brake"]["ttc_s"] == list(bootstrap_mean_interval(capped, groups))
    # paired with sf (the default reference): discordant windows counted from the stored rows
    assert summary["paired"]["reference"] == "sf" and set(summary["paired"]["planners"]) == {"cv", "brake"}
    cr = summary["paired"]["planners"]["brake"]["cr_pct"]
    ref_hit = frames["sf"]["collision"].to_numpy(dtype=bool)
    assert (cr["n_only_planner"], cr["n_only_reference"], cr["n_both"]) == (
        int((hit & ~ref_hit).sum()), int((ref_hit & ~hit).sum()), int((hit & ref_hit).sum()))
    assert cr["p_mcnemar"] == pytest.approx(mcnemar_exact(cr["n_only_planner"], cr["n_only_reference"]), rel=1e-5)
    assert cr["diff"] == pytest.approx(100.0 * (hit.mean() - ref_hit.mean()))
    assert cr["diff_ci95"][0] <= cr["diff"] <= cr["diff_ci95"][1]
    ttc = summary["paired"]["planners"]["brake"]["ttc_s"]
    assert set(ttc) == {"n_pairs", "diff", "diff_ci95"} and ttc["n_pairs"] == 16
    # metrics.md: intervals in the cells and the paired table
    md = (tmp_path / "metrics.md").read_text()
    assert f"| {100 * 6 / 16:.2f} ({100 * low:.2f}–{100 * high:.2f}) |" in md
    assert "Paired with sf" in md and "| brake | ↓ CR (%) | 16 |" in md


def test_intervals_and_paired_entries_are_byte_identical_across_runs(tmp_path: Path) -> None:
    batch = _batch()
    first = tmp_path / "a"
    evaluate(_planners(), batch, first)
    second = tmp_path / "b"
    for built in _planners():  # one planner per run, merged into metrics.json: same result
        evaluate([built], batch, second)
    a, b = (json.loads((d / "metrics.json").read_text()) for d in (first, second))
    assert json.dumps(_without_timing(a["intervals"])) == json.dumps(_without_timing(b["intervals"]))
    assert json.dumps(_without_timing(a["paired"]["planners"])) == json.dumps(_without_timing(b["paired"]["planners"]))


def test_reference_is_chosen_refused_or_taken_from_an_earlier_run(tmp_path: Path) -> None:
    batch = _batch()
    sf, cv, brake = _planners()
    with pytest.raises(ValueError, match="--reference 'nope' is not among the planners"):
        evaluate([cv, brake], batch, tmp_path / "x", EvaluationSettings(reference="nope"))
    assert not (tmp_path / "x").exists()  # refused before anything ran
    # without sf: the first planner of the run
    evaluate([cv, brake], batch, tmp_path / "y")
    assert json.loads((tmp_path / "y" / "metrics.json").read_text())["paired"]["reference"] == "cv"
    # sf stored by an earlier run is the reference of a later one; a single planner has no comparison
    evaluate([sf], batch, tmp_path / "z")
    assert "paired" not in json.loads((tmp_path / "z" / "metrics.json").read_text())
    evaluate([brake], batch, tmp_path / "z")
    paired = json.loads((tmp_path / "z" / "metrics.json").read_text())["paired"]
    assert paired["reference"] == "sf" and list(paired["planners"]) == ["brake"]


def test_cli_evaluate_prints_intervals_and_the_comparison_with_the_reference(tmp_path: Path) -> None:
    path = save_scenarios(_batch(), tmp_path / "s.arrow")
    out = tmp_path / "ev"
    result = runner.invoke(app, ["evaluate", "--scenarios", str(path), "--planner", "sf", "--planner", "cv",
                                 "--planner", "idm", "--goals", "kinematic", "--reference", "cv", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "Paired with cv" in result.output and "| sf | ↓ CR (%) | 16 |" in result.output
    assert "In brackets: 95 % intervals" in result.output
    result = runner.invoke(app, ["evaluate", "--scenarios", str(path), "--planner", "sf", "--goals", "kinematic",
                                 "--reference", "human", "--out", str(out)])
    assert result.exit_code == 2 and "--reference 'human' is not among the planners" in result.output


def test_compare_pairs_a_planner_of_b_with_a_reference_of_a_over_shared_windows(tmp_path: Path) -> None:
    batch = _batch()
    sf, cv, brake = _planners()
    evaluate([sf], batch, tmp_path / "baselines")
    evaluate([cv, brake], batch.take(np.arange(4, 16)), tmp_path / "mine")  # 12 of the 16 windows
    cmp = compare_dirs(tmp_path / "baselines", tmp_path / "mine", reference="sf")
    assert cmp.planners == ["cv", "brake"] and cmp.n_common == {"cv": 12, "brake": 12}
    assert cmp.vehicles_from_ids == 0
    mine = load_planner_results(tmp_path / "mine", "brake")
    theirs = load_planner_results(tmp_path / "baselines", "sf").iloc[4:]
    hit, ref_hit = mine["collision"].to_numpy(dtype=bool), theirs["collision"].to_numpy(dtype=bool)
    cr = cmp.paired["brake"]["cr_pct"]
    assert (cr["n_pairs"], cr["n_only_planner"], cr["n_only_reference"]) == (
        12, int((hit & ~ref_hit).sum()), int((ref_hit & ~hit).sum()))
    assert cmp.metrics_a["brake"]["n"] == 12 and cmp.metrics_a["brake"]["cr_pct"] == pytest.approx(100 * ref_hit.mean())
    text = cmp.markdown()
    assert "every planner of B against sf of A" in text and "| brake vs sf | ↓ CR % | 12 |" in text
    # what is compared, what is left out, and which differences are significant for whom
    assert "- brake (B) vs sf (A): 12 shared windows (left out: 4 only in A); another planner kind" in text
    sr = next(line for line in text.splitlines() if line.startswith("| brake vs sf | ↑ SR % |"))
    assert "**-100.00 (-100.00 to -100.00)**" in sr and sr.endswith("| < 0.001 | worse |")  # 12 discordant of 12
    cr = next(line for line in text.splitlines() if line.startswith("| brake vs sf | ↓ CR % |"))
    assert "**" not in cr and cr.endswith("| 0.125 |  |")  # 4 discordant windows: p = 2 / 2^4, not significant
    result = runner.invoke(app, ["compare", str(tmp_path / "baselines"), str(tmp_path / "mine"), "--reference", "x"])
    assert result.exit_code == 2 and "--reference 'x' is not a planner of" in result.output


def test_rows_stored_without_their_vehicle_are_grouped_by_scenario_id() -> None:
    frame = pd.DataFrame({"scenario_id": ["r01_v5_f100", "r01_v5_f120", "r02_v5_f100"],
                          "vehicle_key": ["abc/5", None, None]})
    groups, from_ids = stored_vehicles(frame)
    assert list(groups) == ["abc/5", "r01_v5", "r02_v5"] and from_ids == 2
    groups, from_ids = stored_vehicles(frame.drop(columns="vehicle_key"))
    assert list(groups) == ["r01_v5", "r01_v5", "r02_v5"] and from_ids == 3
