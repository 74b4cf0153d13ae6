"""Grid PET against hand-computed encounters and the literal per-cell reference."""

from __future__ import annotations

import numpy as np
import pytest
from test_metrics_helpers import constant_speed_plan, inputs, make

from benchmarks.metrics import _reference_pet, synthetic_batch
from letspi.metrics.collision import boxes_overlap
from letspi.metrics.distance import distances
from letspi.metrics.inputs import MetricInputs
from letspi.metrics.pet import pet_grid
from letspi.scenario.build import VehicleSpec

# Geometry chosen so that with 1 m cells everything moves exactly one cell per frame:
# speed 25 m/s * 0.04 s = 1 m; boxes 4 m x 1.8 m, centres offset by 0.25 m from cell edges.
# A box occupies the cells whose centre (i + 0.5 m) it covers strictly, so a 4 m box with its
# rear edge at k + 0.25 m (k integer) covers the centres k + 0.5 .. k + 3.5: columns k .. k + 3.
V = 25.0
CAR = {"length_m": 4.0, "width_m": 1.8}


def _lane_change_plan() -> tuple[np.ndarray, np.ndarray]:
    f = np.arange(125)
    y = 3.75 * np.clip((f - 40) / 20.0, 0.0, 1.0)  # into the left lane over steps 40..60
    return constant_speed_plan(V, x0_m=0.25, y_m=y)


def test_pet_lane_change_behind_neighbour() -> None:
    # Neighbour in the left lane, centre 10.25 m ahead: at step f (t = (f + 1) * 0.04) its box is
    # [9.25 + f, 13.25 + f] -> columns 9+f..12+f (centres 9.5+f..12.5+f); the ego's
    # [f - 0.75, f + 3.25] -> columns f-1..f+2. They share a column when f1 - 13 <= f2 <= f1 - 7,
    # so the neighbour's last frame in a cell is 7 frames before the ego's first: PET = 0.28 s
    # (bumper gap 6 m / 25 m/s = 0.24 s, plus one frame of sampling: the neighbour leaves the
    # centre between two frames).
    b = make([VehicleSpec(x0_m=10.25, speed_mps=V, lane_offset=1, **CAR)], ego_length_m=4.0)
    xy, v = _lane_change_plan()
    r = pet_grid(inputs(b, xy, v), cell_m=1.0)
    assert r.min_pet_s[0] == pytest.approx(0.28)
    assert r.min_pet_nbr[0] == 0
    assert not r.ego_first[0, 0]
    # the neighbour (y 2.85..4.65) covers the row centres 3.5 and 4.5; the ego's box covers 3.5
    # when y + 0.9 > 3.5, i.e. 3.75 (f - 40) / 20 > 2.6: first at step 54
    assert r.min_pet_step[0] == 54


def test_pet_lane_change_ahead_of_follower() -> None:
    # Follower in the left lane, centre 9.75 m behind: box [f - 10.75, f - 6.75] -> columns
    # f-11..f-8; shared with the ego's f-1..f+2 when f1 + 7 <= f2 <= f1 + 13: 0.28 s, ego first.
    b = make([VehicleSpec(x0_m=-9.75, speed_mps=V, lane_offset=1, **CAR)], ego_length_m=4.0)
    xy, v = _lane_change_plan()
    r = pet_grid(inputs(b, xy, v), cell_m=1.0)
    assert r.min_pet_s[0] == pytest.approx(0.28)
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
    # columns 9+f..12+f and f-1..f+2 as above: the bumper-to-bumper time gap 0.24 s + one frame
    assert r.min_pet_s[0] == pytest.approx(0.28)


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


def test_pet_side_by_side_without_contact_is_undefined() -> None:
    # Ego box y in (-0.7, 1.1), neighbour's in (1.4, 3.2): 0.3 m apart, both reaching into the
    # 0.5 m cell row [1.0, 1.5) whose centre 1.25 neither covers. They drive side by side (the
    # same speed) or pass slowly (2 m/s faster) and never touch: no shared cell, PET undefined.
    for speed in (30.0, 32.0):
        b = make([VehicleSpec(x0_m=0.0, speed_mps=speed, y_offset_m=2.3)])
        xy, v = constant_speed_plan(30.0, y_m=0.2)
        inp = inputs(b, xy, v)
        r = pet_grid(inp, cell_m=0.5)
        assert np.isinf(r.min_pet_s[0]) and r.min_pet_nbr[0] == -1
        assert not boxes_overlap(inp).any()
        assert distances(inp).min_box_gap_m[0] == pytest.approx(0.3, abs=1e-5)


def _crossing_inputs(nbr_x_m: float = 33.0) -> MetricInputs:
    """Ego 4 x 2 m along +x at 20 m/s from x = 0; a 2 x 4 m box crossing +y at 10 m/s from y = -1."""
    t = (np.arange(125) + 1) * 0.04
    ego_xy = np.stack([20.0 * t, np.zeros_like(t)], -1)[None]
    ego_v = np.broadcast_to([20.0, 0.0], ego_xy.shape).copy()
    nbr_xy = np.stack([np.full_like(t, nbr_x_m), -1.0 + 10.0 * t], -1)[None, None]
    nbr_v = np.broadcast_to([0.0, 10.0], nbr_xy.shape).copy()
    return MetricInputs(
        ego_xy_m=ego_xy, ego_vxy_mps=ego_v, ego_length_m=np.array([4.0]), ego_width_m=np.array([2.0]),
        nbr_xy_m=nbr_xy, nbr_vxy_mps=nbr_v, nbr_valid=np.ones((1, 1, 125), bool),
        nbr_length_m=np.array([[2.0]]), nbr_width_m=np.array([[4.0]]),
    )


def test_pet_crossing_hand_computed() -> None:
    # Conflict area x in (32, 34), y in (-1, 1). The crossing box leaves the point (x, 1) when its
    # rear edge y - 2 passes 1: t = 0.4 s; the ego's front (x + 2) reaches x = 32 at t = 1.5 s.
    # Continuous PET = 1.1 s (the crossing box first). On 0.5 m cells: the last frame covering the
    # row centre y = 0.75 is t = 0.36 s (y(t) < 2.75), the first ego frame covering the column
    # centre x = 32.25 is t = 1.52 s (20 t + 2 > 32.25): grid PET 1.16 s, within
    # cell / 20 + cell / 10 + dt = 0.115 s of the continuous value.
    r = pet_grid(_crossing_inputs(), cell_m=0.5)
    assert r.min_pet_s[0] == pytest.approx(1.16, abs=1e-9)
    assert abs(r.min_pet_s[0] - 1.1) <= 0.5 / 20 + 0.5 / 10 + 0.04
    assert not r.ego_first[0, 0] and r.min_pet_nbr[0] == 0
    assert r.min_pet_step[0] == 37  # t = 1.52 s, the ego (second) enters the conflict cell
    # crossing 3 m further on: continuous PET 1.25 s; the first ego frame covering x = 35.25 is
    # t = 1.68 s (20 t + 2 > 35.25), so grid PET 1.32 s
    later = pet_grid(_crossing_inputs(36.0), cell_m=0.5)
    assert later.min_pet_s[0] == pytest.approx(1.32, abs=1e-9)
