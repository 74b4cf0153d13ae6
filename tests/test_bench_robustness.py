"""Degenerate scenes through every planner and metric: no crash, no NaN (``python -m benchmarks.speed robustness``)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

import benchmarks.robustness as robustness
from benchmarks.degenerate import DEGENERATE_KINDS, degenerate_scenarios, scene_kind
from benchmarks.speed import app as speed_app
from letspi.constants import MAX_NEIGHBOURS, T0_INDEX


def test_degenerate_scenes_are_what_they_claim() -> None:
    batch = degenerate_scenarios(12 * len(DEGENERATE_KINDS), seed=3)
    kinds = np.array([scene_kind(s) for s in batch.scenario_id])
    assert sorted(set(kinds)) == sorted(DEGENERATE_KINDS)
    alone = batch.take(np.flatnonzero(kinds == "no_neighbours"))
    assert not alone.nbr_valid.any()
    overlap = batch.take(np.flatnonzero(kinds == "overlap"))
    assert overlap.nbr_valid[:, :, T0_INDEX].sum(axis=1).tolist() == [MAX_NEIGHBOURS] * len(overlap)
    dx = np.abs(overlap.nbr_xy_m[:, :, T0_INDEX, 0])
    assert (dx < 0.5 * (overlap.nbr_length_m + overlap.ego_length_m[:, None])).all()  # boxes overlap
    still = batch.take(np.flatnonzero(kinds == "zero_speed"))
    assert (still.ego_vxy_mps == 0).all()
    narrow = batch.take(np.flatnonzero(kinds == "one_lane"))
    assert (np.isfinite(narrow.marking_y_m).sum(axis=1) == 2).all()
    gaps = batch.take(np.flatnonzero(kinds == "nan_gaps"))
    nan = np.isnan(gaps.nbr_xy_m[..., 0])
    assert (nan & gaps.nbr_valid).any() and (nan & ~gaps.nbr_valid).any()


def test_bench_robustness_has_no_crash_and_no_nan() -> None:
    result = CliRunner().invoke(speed_app, ["robustness", "--n", "30", "--n-llm", "6", "--json"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert out["scenarios_by_kind"] == dict.fromkeys(DEGENERATE_KINDS, 5)
    # every kind of the planner table; mlp has no weights unless given (--mlp-weights): skipped, and said so
    assert set(out["planners"]) == {"human", "cv", "idm", "sf", "sf-opt", "sf-check", "gnp", "frenet", "llm",
                                    "letspi-memory", "letspi-fast", "letspi-fs"}
    assert list(out["skipped"]) == ["mlp"] and "--mlp-weights" in out["skipped"]["mlp"]
    assert out["crashes"] == 0 and out["nan_values"] == 0 and out["nan_aggregates"] == 0
    assert all(p["metrics_checked"] >= 10 for p in out["planners"].values())
    assert out["planners"]["llm"]["scenarios"] == 6 and out["planners"]["sf"]["scenarios"] == 30


def test_a_nan_metric_is_counted_and_fails_the_bench(monkeypatch: pytest.MonkeyPatch) -> None:
    real = robustness.compute_metrics

    def leaky(*args: object, **kwargs: object):  # type: ignore[no-untyped-def]
        metrics = real(*args, **kwargs)  # type: ignore[arg-type]
        metrics["min_ttc_s"][:] = np.nan
        return metrics

    monkeypatch.setattr(robustness, "compute_metrics", leaky)
    monkeypatch.setattr(robustness, "PLAIN_PLANNERS", ("cv",))
    result = CliRunner().invoke(speed_app, ["robustness", "--n", "6", "--n-llm", "0"])
    assert result.exit_code == 1
    assert "cv NaN by metric: {'min_ttc_s': 6}" in result.output
