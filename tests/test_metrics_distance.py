"""Centre distance vs box gap, collisions (box overlap and the 2 m variant), relative position."""

from __future__ import annotations

import numpy as np
import pytest
from test_metrics_helpers import constant_speed_plan, inputs, make

from letspi.metrics.collision import collisions
from letspi.metrics.distance import box_gap, distances
from letspi.metrics.relative import classify_offset, relative_position
from letspi.scenario.build import VehicleSpec


def test_box_gap_vs_centre_distance_hand_pair() -> None:
    # centres 8 m ahead and 3 m left; 4.5 x 1.8 boxes: gaps 3.5 m along x, 1.2 m along y
    assert box_gap(np.array(8.0), np.array(3.0), np.array(4.5), np.array(1.8)) == pytest.approx(np.hypot(3.5, 1.2))
    assert box_gap(np.array(3.0), np.array(-1.0), np.array(4.5), np.array(1.8)) == 0.0  # overlapping
    assert box_gap(np.array(-10.0), np.array(0.5), np.array(4.5), np.array(1.8)) == pytest.approx(5.5)  # behind


def test_distances_minima_and_argmin() -> None:
    # slot 0: far car in the right lane; slot 1: same speed, 8 m ahead, 3 m left (constant offset);
    # slot 2: faster car from behind in the ego's lane, closest centre distance at the last step
    b = make(
        [
            VehicleSpec(x0_m=60.0, speed_mps=30.0, lane_offset=-1),
            VehicleSpec(x0_m=8.0, speed_mps=30.0, y_offset_m=3.0),
            VehicleSpec(x0_m=-40.0, speed_mps=36.0),
        ]
    )
    xy, v = constant_speed_plan(30.0)
    r = distances(inputs(b, xy, v))
    # slot 2 at the last step: dx = -40 + 6 * 5 = -10 -> centre 10 m, box gap 5.5 m
    assert r.min_centre_dist_m[0] == pytest.approx(np.hypot(8.0, 3.0), abs=1e-4)
    assert r.min_centre_dist_nbr[0] == 1
    assert r.min_box_gap_m[0] == pytest.approx(np.hypot(3.5, 1.2), abs=1e-4)
    assert r.min_gap_nbr[0] == 1
    assert r.box_gap_m[0, 2, -1] == pytest.approx(5.5, abs=1e-3)


def test_no_neighbours_gives_inf_and_minus_one() -> None:
    xy, v = constant_speed_plan(30.0)
    r = distances(inputs(make([]), xy, v))
    assert np.isinf(r.min_centre_dist_m[0]) and r.min_gap_step[0] == -1 and r.min_gap_nbr[0] == -1


def test_rear_end_collision_at_known_step() -> None:
    # bumper gap 20.1 m closing at 5 m/s: gap 20.1 - 0.2 (f + 1) < 0 first at f = 100
    b = make([VehicleSpec(x0_m=0.0, speed_mps=30.0, lane_offset=1), VehicleSpec(x0_m=24.6, speed_mps=25.0)])
    xy, v = constant_speed_plan(30.0)
    r = collisions(inputs(b, xy, v))
    assert r.collision[0] and r.collision_step[0] == 100 and r.collision_nbr[0] == 1
    # 2 m variant (longitudinal gap to a car in the path): gap < 2 first at f = 91 - 1 = 90
    assert r.collision_2m[0] and r.collision_2m_step[0] == 90 and r.collision_2m_nbr[0] == 1


def test_adjacent_lane_pass_is_not_a_collision_by_default() -> None:
    # the alongside car in the next lane: box gap 3.75 - 1.8 = 1.95 m < 2 m
    b = make([VehicleSpec(x0_m=0.0, speed_mps=30.0, lane_offset=1)])
    xy, v = constant_speed_plan(30.0)
    inp = inputs(b, xy, v)
    r = collisions(inp)
    assert not r.collision[0] and not r.collision_2m[0]
    assert collisions(inp, mode="box_gap").collision_2m[0]  # the literal box-gap reading flags it
    assert not collisions(inp, mode="centre_distance").collision_2m[0]


def test_classify_offset() -> None:
    dx = np.array([10.0, -10.0, 1.0, -2.0, 30.0, 5.0, np.nan])
    dy = np.array([0.5, -0.3, 3.75, -3.75, 3.75, 10.0, 0.0])
    got = classify_offset(dx, dy, np.full(7, 4.5), np.full(7, 1.8))
    assert list(got) == ["front", "rear", "side", "side", "front", "side", "none"]
    lr = classify_offset(dx[2:4], dy[2:4], np.full(2, 4.5), np.full(2, 1.8), left_right=True)
    assert list(lr) == ["left", "right"]


def test_relative_position_of_argmin() -> None:
    b = make([VehicleSpec(x0_m=0.0, speed_mps=30.0, lane_offset=1), VehicleSpec(x0_m=24.6, speed_mps=25.0)])
    xy, v = constant_speed_plan(30.0)
    inp = inputs(b, xy, v)
    r = collisions(inp)
    assert relative_position(inp, r.collision_step, r.collision_nbr)[0] == "front"
    assert relative_position(inp, np.array([5]), np.array([0]), left_right=True)[0] == "left"
    assert relative_position(inp, np.array([-1]), np.array([-1]))[0] == "none"
