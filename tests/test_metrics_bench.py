"""Vectorised metrics == plain per-scenario loops; the benchmark runs."""

from __future__ import annotations

import numpy as np

from benchmarks.metrics import _reference_core, bench_metrics, synthetic_batch
from letspi.metrics.distance import distances
from letspi.metrics.inputs import MetricInputs
from letspi.metrics.ttc import rear_ttc_1d, ttc_1d
from letspi.metrics.ttc2d import ttc_2d


def test_vectorised_matches_loop_reference() -> None:
    batch, xy, v, _ = synthetic_batch(60, seed=11)
    inp = MetricInputs.from_batch(batch, xy, v)
    got = {
        "min_ttc_s": ttc_1d(inp).min_ttc_s,
        "min_rear_ttc_s": rear_ttc_1d(inp).min_ttc_s,
        "min_ttc2d_s": ttc_2d(inp).min_ttc2d_s,
        "min_centre_dist_m": distances(inp).min_centre_dist_m,
        "min_box_gap_m": distances(inp).min_box_gap_m,
    }
    refs = [_reference_core(inp, b) for b in range(len(batch))]
    for key, arr in got.items():
        np.testing.assert_allclose(arr, [r[key] for r in refs], rtol=1e-9, atol=1e-9, err_msg=key)
    assert np.isfinite(got["min_ttc_s"]).sum() > 5 and np.isinf(got["min_ttc_s"]).sum() > 0
    assert np.isfinite(got["min_rear_ttc_s"]).sum() > 5 and np.isinf(got["min_rear_ttc_s"]).sum() > 0


def test_bench_runs_small() -> None:
    res = bench_metrics(n_scenarios=64, n_reference=5)
    assert res["full_sps"] > 0 and res["core_speedup"] > 0 and res["pet_speedup"] > 0
