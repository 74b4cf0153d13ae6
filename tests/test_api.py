"""letspi.api: the Python API does what the CLI does (same files, keys, resume) and returns DataFrames."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from test_evaluation_statistics import _batch

import letspi.api as lp
from letspi.constants import N_FUTURE
from letspi.scenario.store import save_scenarios


def test_load_plan_evaluate_and_read_results_as_dataframes(tmp_path: Path) -> None:
    path = save_scenarios(_batch(), tmp_path / "s.arrow")
    batch = lp.load_scenarios(path, limit=12)
    assert len(batch) == 12 and len(lp.load_scenarios(path, rows=[3, 5])) == 2
    built = lp.planners("sf", "fast=cv", goals="kinematic")
    assert [b.name for b in built] == ["sf", "fast"]
    planned = lp.plan(built[0], batch.take(np.arange(3)))
    assert planned.xy_m.shape == (3, N_FUTURE, 2)
    results = lp.evaluate(built, path, tmp_path / "ev", limit=12)
    assert results.planners == ["sf", "fast"] and results.reference == "sf"
    # the same files as `letspi evaluate`
    assert results.metrics == json.loads((tmp_path / "ev" / "metrics.json").read_text())["planners"]
    assert results.table().rstrip("\n") == (tmp_path / "ev" / "metrics.md").read_text().rstrip("\n")
    summary = results.summary()
    assert list(summary.index) == ["sf", "fast"] and summary.loc["fast", "n"] == 12
    assert summary.loc["fast", "cr_pct"] == results.metrics["fast"]["cr_pct"]
    low, high = summary.loc["fast", "cr_pct_low"], summary.loc["fast", "cr_pct_high"]
    assert [low, high] == results.intervals["fast"]["cr_pct"]
    rows = results.per_scenario("fast")
    assert len(rows) == 12 and {"scenario_id", "vehicle_key", "collision", "min_ttc_s", "inference_s"} <= set(rows)
    assert 100 * rows["collision"].mean() == pytest.approx(results.metrics["fast"]["cr_pct"])
    paired = results.paired_summary()
    cr = paired[(paired.planner == "fast") & (paired.key == "cr_pct")].iloc[0]
    assert cr["reference"] == "sf" and cr["n_pairs"] == 12 and cr["diff_low"] <= cr["diff"] <= cr["diff_high"]
    assert cr["n_only_planner"] == results.raw["paired"]["planners"]["fast"]["cr_pct"]["n_only_planner"]
    # a second call resumes: nothing is planned again, a new planner joins
    again = lp.evaluate(lp.planners("idm", goals="kinematic"), path, tmp_path / "ev", limit=12)
    assert again.planners == ["sf", "fast", "idm"]
    assert again.per_scenario("sf")["inference_s"].equals(results.per_scenario("sf")["inference_s"])
    assert lp.open_results(tmp_path / "ev").summary().shape[0] == 3
    assert results.report(with_diagrams=False).name == "report.html"


def test_api_errors_name_what_is_wrong(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="name at least one planner"):
        lp.planners()
    with pytest.raises(ValueError, match="limit or rows"):
        lp.load_scenarios(tmp_path / "x.arrow", limit=1, rows=[0])
    with pytest.raises(FileNotFoundError, match="no metrics.json"):
        lp.open_results(tmp_path)
    path = save_scenarios(_batch(), tmp_path / "s.arrow")
    results = lp.evaluate(lp.planners("cv"), path, tmp_path / "ev", limit=4)
    with pytest.raises(KeyError, match="has no planner 'sf'"):
        results.per_scenario("sf")
    assert results.paired_summary().empty and results.reference is None
