"""Grid PET against hand-computed encounters and the literal per-cell reference."""

from __future__ import annotations

import numpy as np
import pytest
from test_metrics_helpers import constant_speed_plan, inputs, make

from letspi.bench.metrics import _reference_pet, synthetic_batch
from letspi.metrics._common import MetricInputs
from letspi.metrics.pet import pet_grid
from letspi.scenario.build import VehicleSpec

# Geometry chosen so that with 1 m cells everything moves exactly one cell per frame:
# speed 25 m/s * 0.04 s = 1 m; boxes 4 m x 1.8 m, centres offset by 0.25 m from cell edges.
V = 25.0
CAR = {"length_m": 4.0, "width_m": 1.8}


def _lane_change_plan() -> tuple[np.ndarray, np.ndarray]:
    f = np.arange(125)
    y = 3.75 * np.clip((f - 40) / 20.0, 0.0, 1.0)  # into the left lane over steps 40..60
    return constant_speed_plan(V, x0_m=0.25, y_m=y)


def test_pet_lane_change_behind_neighbour() -> None:
    # Neighbour in the left lane, centre 10.25 m ahead: at step f (t = (f + 1) * 0.04) its box is
    # [9.25 + f, 13.25 + f] -> columns 9+f..13+f; the ego's [f - 0.75, f + 3.25] -> columns
    # f-1..f+3. They share a column when f1 - 14 <= f2 <= f1 - 6, so the neighbour leaves a cell
    # 6 frames before the ego enters it: PET = 0.24 s (= bumper gap 6 m / 25 m/s).
    b = make([VehicleSpec(x0_m=10.25, speed_mps=V, lane_offset=1, **CAR)], ego_length_m=4.0)
    xy, v = _lane_change_plan()
    r = pet_grid(inputs(b, xy, v), cell_m=1.0)
    assert r.min_pet_s[0] == pytest.approx(0.24)
    assert r.min_pet_nbr[0] == 0
    assert not r.ego_first[0, 0]
    # the ego's box reaches the left lane's first cell row (y >= 2) when y > 1.1 m: step 46
    assert r.min_pet_step[0] == 46


def test_pet_lane_change_ahead_of_follower() -> None:
    # Follower in the left lane, centre 9.75 m behind: box [f - 10.75, f - 6.75] -> columns
    # f-11..f-7; shared with the ego's f-1..f+3 when f1 + 6 <= f2 <= f1 + 14: 0.24 s, ego first.
    b = make([VehicleSpec(x0_m=-9.75, speed_mps=V, lane_offset=1, **CAR)], ego_length_m=4.0)
    xy, v = _lane_change_plan()
    r = pet_grid(inputs(b, xy, v), cell_m=1.0)
    assert r.min_pet_s[0] == pytest.approx(0.24)
    assert r.ego_first[0, 0]


def test_pet_undefined_without_shared_cells() -> None:
    # ego keeps its lane; neighbours only in the adjacent lanes -> no shared cell -> +inf
    b = make(
        [
            VehicleSpec(x0_m=10.25, speed_mps=V, lane_offset=1, **CAR),
            VehicleSpec(x0_m=-20.0, speed_mps=V, lane_offset=-1),
        ],
        ego_length_m=4.0,
    )
    xy, v = constant_speed_plan(V, x0_m=0.25)
    r = pet_grid(inputs(b, xy, v), cell_m=1.0)
    assert np.isinf(r.min_pet_s[0]) and r.min_pet_nbr[0] == -1 and r.min_pet_step[0] == -1
    assert np.isinf(r.pet_s).all()


def test_pet_same_lane_following_is_time_gap() -> None:
    b = make([VehicleSpec(x0_m=10.25, speed_mps=V, **CAR)], ego_length_m=4.0)
    xy, v = constant_speed_plan(V, x0_m=0.25)
    r = pet_grid(inputs(b, xy, v), cell_m=1.0)
    assert r.min_pet_s[0] == pytest.approx(0.24)  # the bumper-to-bumper time gap


def test_pet_leader_beyond_horizon_reach_is_undefined() -> None:
    # leader 200 m ahead at the same speed: the ego never reaches cells the leader used after t = 0
    b = make([VehicleSpec(x0_m=200.0, speed_mps=V, **CAR)], ego_length_m=4.0)
    xy, v = constant_speed_plan(V, x0_m=0.25)
    assert np.isinf(pet_grid(inputs(b, xy, v), cell_m=1.0).min_pet_s[0])


@pytest.mark.parametrize("cell_m", [0.5, 1.0])
def test_pet_matches_literal_grid_reference(cell_m: float) -> None:
    batch, xy, v, _ = synthetic_batch(40, seed=7)
    inp = MetricInputs.from_batch(batch, xy, v)
    got = pet_grid(inp, cell_m=cell_m).min_pet_s
    ref = np.array([_reference_pet(inp, b, cell_m) for b in range(len(batch))])
    assert np.isfinite(ref).sum() > 10  # the random batch does contain encounters
    np.testing.assert_allclose(got, ref, atol=1e-12)
