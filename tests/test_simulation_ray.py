"""Closed loop on a local Ray instance (skipped without the optional extra ``ray``)."""

from __future__ import annotations

import importlib.util
from collections.abc import Iterator
from dataclasses import replace
from typing import Any

import numpy as np
import pytest
from test_simulation_support import generated_batch

from letspi.scenario.types import ScenarioBatch
from letspi.simulation import ClosedLoopChunk, ClosedLoopConfig, PlannerSpec, run_closed_loop

pytestmark = [
    pytest.mark.sumo,
    pytest.mark.slow,
    pytest.mark.skipif(importlib.util.find_spec("ray") is None,
                       reason="ray is not installed (optional extra: pip install 'letspi[ray]')"),
]


@pytest.fixture(scope="module")
def local_ray() -> Iterator[Any]:
    import ray

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield ray
    finally:
        ray.shutdown()


def test_ray_actors_simulate_a_small_batch_like_the_local_engine(
    local_ray: Any, tmp_path_factory: pytest.TempPathFactory
) -> None:
    batch: ScenarioBatch = generated_batch(tmp_path_factory.mktemp("cl_ray"), n=8, seed=9)
    cfg = ClosedLoopConfig(mode="closed-loop-reactive", chunk_size=4)
    chunks = list(run_closed_loop(PlannerSpec.of("idm"), batch, replace(cfg, workers=2, ray_address="local")))
    assert local_ray.is_initialized()
    assert len(chunks) == 2
    on_ray = ClosedLoopChunk.concat(chunks)
    assert sorted(on_ray.indices.tolist()) == list(range(8))
    local = ClosedLoopChunk.concat(list(run_closed_loop(PlannerSpec.of("idm"), batch, cfg)))
    a, b = local.take(np.argsort(local.indices)), on_ray.take(np.argsort(on_ray.indices))
    np.testing.assert_allclose(a.ego_xy_m, b.ego_xy_m, atol=1e-9)
    np.testing.assert_array_equal(a.nbr_valid, b.nbr_valid)
