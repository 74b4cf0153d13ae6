"""The kernel timings of ``python -m benchmarks.speed physics``: new and replaced kernels run on the same
scenes, agree bit for bit, and the comparison notices a one-ulp difference."""

from __future__ import annotations

import json

import numpy as np
from typer.testing import CliRunner

from benchmarks.kernels import KERNELS, identical
from benchmarks.physics import synthetic_batch
from benchmarks.speed import app as speed_app
from letspi.physics.neighbours import predict_idm
from letspi.physics.types import NeighbourPrediction


def test_bench_physics_times_each_kernel_beside_the_one_it_replaced() -> None:
    result = CliRunner().invoke(speed_app, ["physics", "--n", "0", "--frenet-n", "0", "--kernel-n", "6", "--json"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert not any(k.startswith(("rollout_", "metrics_", "frenet_")) for k in out)  # --n 0, --frenet-n 0 skip them
    assert out["kernel_n_scenarios"] == 6 and out["kernel_sf_opt_candidates"] == 27
    for name in KERNELS:
        assert out[f"kernel_{name}_identical"] == 1.0, name
        new, old = out[f"kernel_{name}_new_cpu_ms"], out[f"kernel_{name}_old_cpu_ms"]
        assert new > 0 and old > 0 and out[f"kernel_{name}_speedup"] == old / new
    assert out["kernel_load_1min_start"] >= 0 and out["kernel_load_1min_end"] >= 0


def test_identical_notices_one_ulp_and_takes_nan_as_equal() -> None:
    pred = predict_idm(synthetic_batch(4, seed=1).history())
    copy = NeighbourPrediction(*(np.array(a) for a in pred))
    assert identical(pred, copy)
    copy.xy_m[2, 0, 7, 0] = np.nextafter(copy.xy_m[2, 0, 7, 0], np.inf)
    assert not identical(pred, copy)
    with_nan = NeighbourPrediction(*(np.array(a) for a in pred))
    with_nan.xy_m[0, 0, 0, 0] = np.nan
    same_nan = NeighbourPrediction(*(np.array(a) for a in with_nan))
    assert identical(with_nan, same_nan) and not identical(pred, with_nan)
