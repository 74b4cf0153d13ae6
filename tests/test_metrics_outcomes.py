"""``compute_outcomes`` is the subset of ``compute_metrics`` a candidate search needs: same values."""

from __future__ import annotations

import numpy as np
from test_metrics_helpers import constant_speed_plan, make

from letspi.metrics import MetricsConfig, compute_metrics
from letspi.metrics.compute import compute_outcomes
from letspi.scenario.build import VehicleSpec
from letspi.scenario.types import concat_batches


def _scenes_and_plans() -> tuple[object, np.ndarray, np.ndarray]:
    scenes = [
        make([VehicleSpec(40.0, 30.0), VehicleSpec(-30.0, 30.0)]),  # safe at 30 m/s
        make([VehicleSpec(20.0, 20.0)]),  # a slower leader: driving on at 30 m/s hits it (at fault)
        make([VehicleSpec(-8.0, 35.0)]),  # a faster follower: hits a braking ego from behind
        make([VehicleSpec(3.0, 30.0, lane_offset=1)]),  # a lane change into a car alongside
    ]
    plans = [
        constant_speed_plan(30.0),
        constant_speed_plan(30.0),
        constant_speed_plan(20.0),
        constant_speed_plan(30.0, y_m=np.linspace(0.0, 3.75, 125)),
    ]
    return (concat_batches(scenes), np.concatenate([p[0] for p in plans]), np.concatenate([p[1] for p in plans]))


def test_outcomes_equal_the_metrics_columns_and_progress_is_the_end_x() -> None:
    batch, xy, v = _scenes_and_plans()
    m = compute_metrics(batch, xy, v)  # type: ignore[arg-type]
    o = compute_outcomes(batch, xy, v)  # type: ignore[arg-type]
    for name in ("collision", "collision_at_fault", "success", "min_ttc_s"):
        np.testing.assert_array_equal(getattr(o, name), np.asarray(m[name]), err_msg=name)
    assert o.collision.tolist() == [False, True, True, True]
    assert o.collision_at_fault.tolist()[:2] == [False, True]
    np.testing.assert_allclose(o.progress_m, xy[:, -1, 0])


def test_outcomes_do_not_depend_on_the_chunking() -> None:
    batch, xy, v = _scenes_and_plans()
    whole = compute_outcomes(batch, xy, v)  # type: ignore[arg-type]
    chunked = compute_outcomes(batch, xy, v, MetricsConfig(chunk_size=3))  # type: ignore[arg-type]
    for name in ("collision", "collision_at_fault", "success", "min_ttc_s", "progress_m"):
        np.testing.assert_array_equal(getattr(whole, name), getattr(chunked, name))
