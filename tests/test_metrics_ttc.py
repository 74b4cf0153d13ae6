"""1-D TTC, 2-D TTC and DRAC against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest
from test_metrics_helpers import constant_speed_plan, inputs, make

from letspi.metrics.drac import drac
from letspi.metrics.ttc import rear_ttc_1d, ttc_1d, ttc_from_gap
from letspi.metrics.ttc2d import box_ttc_2d, ttc_2d
from letspi.scenario.build import VehicleSpec


def test_ttc_from_gap_basic_cases() -> None:
    gap = np.array([20.0, 20.0, 0.0, -1.0, np.inf])
    dv = np.array([5.0, -2.0, 3.0, -3.0, np.nan])
    np.testing.assert_allclose(ttc_from_gap(gap, dv), [4.0, np.inf, 0.0, 0.0, np.inf])


def test_ttc_closing_on_leader_hand_computed() -> None:
    # slot 0: slower car ahead in the LEFT lane (not preceding); slot 1: leader 40 m ahead bumper
    # to bumper (centre 44.5 m, both 4.5 m long) at 25 m/s; ego plan 30 m/s.
    b = make([VehicleSpec(x0_m=10.0, speed_mps=20.0, lane_offset=1), VehicleSpec(x0_m=44.5, speed_mps=25.0)])
    xy, v = constant_speed_plan(30.0)
    r = ttc_1d(inputs(b, xy, v))
    # step f at t = (f+1)*0.04: gap = 40 - 5 t, TTC = gap / 5
    assert r.ttc_s[0, 0] == pytest.approx((40.0 - 0.2) / 5.0, abs=1e-4)
    assert r.preceding.nbr[0, 0] == 1
    assert r.min_ttc_s[0] == pytest.approx(3.0, abs=1e-4)  # last step: gap 15 m
    assert r.min_ttc_step[0] == 124
    assert r.min_ttc_nbr[0] == 1


def test_ttc_faster_leader_is_inf() -> None:
    b = make([VehicleSpec(x0_m=30.0, speed_mps=35.0)])
    xy, v = constant_speed_plan(30.0)
    r = ttc_1d(inputs(b, xy, v))
    assert np.isinf(r.ttc_s).all()
    assert np.isinf(r.min_ttc_s[0]) and r.min_ttc_step[0] == -1 and r.min_ttc_nbr[0] == -1


def test_ttc_overlapping_is_zero() -> None:
    b = make([VehicleSpec(x0_m=3.0, speed_mps=30.0)])  # centres 3 m apart, 4.5 m cars
    xy, v = constant_speed_plan(30.0)
    r = ttc_1d(inputs(b, xy, v))
    assert r.min_ttc_s[0] == 0.0 and r.min_ttc_step[0] == 0 and r.min_ttc_nbr[0] == 0


def test_ttc_follows_planned_lane_change() -> None:
    # slow car in the left lane; the ego moves into the left lane at step 50 -> it becomes preceding
    b = make([VehicleSpec(x0_m=60.0, speed_mps=20.0, lane_offset=1)])
    y = np.where(np.arange(125) >= 50, 3.75, 0.0)
    xy, v = constant_speed_plan(30.0, y_m=y)
    r = ttc_1d(inputs(b, xy, v))
    assert np.isinf(r.ttc_s[0, :50]).all()
    gap = 60.0 - 4.5 - 10.0 * 51 * 0.04
    assert r.ttc_s[0, 50] == pytest.approx(gap / 10.0, abs=1e-4)


@pytest.mark.parametrize(
    ("p", "v", "expected"),
    [
        ((1.0, 0.5), (0.0, 0.0), 0.0),  # already overlapping, at rest
        ((1.0, 0.5), (3.0, -1.0), 0.0),  # already overlapping, moving
        ((0.0, 3.75), (-5.0, 0.0), np.inf),  # parallel in the next lane: never overlaps laterally
        ((10.0, 0.0), (5.0, 0.0), np.inf),  # diverging (leader pulls away)
        ((20.0, 3.75), (-5.0, -1.0), 3.1),  # crossing: x in (3.1, 4.9), y in (1.95, 5.55)
        ((20.0, 3.75), (-10.0, -1.0), 1.95),  # crossing: x in (1.55, 2.45), y binding at 1.95
        ((20.0, 3.75), (-10.0, -0.5), np.inf),  # x in (1.55, 2.45), y in (3.9, 11.1): miss
        ((0.0, 3.75), (0.0, -0.5), 3.9),  # side-by-side, drifting in: (3.75 - 1.8) / 0.5
    ],
)
def test_box_ttc_2d_cases(p: tuple[float, float], v: tuple[float, float], expected: float) -> None:
    got = box_ttc_2d(np.array(p[0]), np.array(p[1]), np.array(v[0]), np.array(v[1]), np.array(4.5), np.array(1.8))
    assert got == pytest.approx(expected, abs=1e-12)


def test_ttc2d_batch_rear_end_and_argmin() -> None:
    # slot 0: car alongside in the left lane (2-D TTC inf); slot 1: leader 20 m gap closing at 5 m/s
    b = make([VehicleSpec(x0_m=0.0, speed_mps=30.0, lane_offset=1), VehicleSpec(x0_m=24.6, speed_mps=25.0)])
    xy, v = constant_speed_plan(30.0)
    r = ttc_2d(inputs(b, xy, v))
    assert np.isinf(r.ttc_s[0, 0]).all()
    assert r.ttc_s[0, 1, 0] == pytest.approx((20.1 - 0.2) / 5.0, abs=1e-4)
    assert r.min_ttc2d_s[0] == 0.0
    assert r.min_ttc2d_step[0] == 100  # gap 20.1 - 0.2 (f + 1) < 0 first at f = 100
    assert r.min_ttc2d_nbr[0] == 1


def test_drac_hand_computed() -> None:
    b = make([VehicleSpec(x0_m=44.5, speed_mps=25.0)])
    xy, v = constant_speed_plan(30.0)
    r = drac(inputs(b, xy, v))
    assert r.drac_mps2[0, 0] == pytest.approx(25.0 / (2 * 39.8), rel=1e-5)
    assert r.max_drac_mps2[0] == pytest.approx(25.0 / 30.0, rel=1e-5)  # last step, gap 15 m
    assert r.max_drac_step[0] == 124 and r.max_drac_nbr[0] == 0


def test_drac_no_closing_is_zero_and_overlap_inf() -> None:
    b = make([VehicleSpec(x0_m=30.0, speed_mps=35.0), VehicleSpec(x0_m=0.0, speed_mps=30.0, lane_offset=1)])
    xy, v = constant_speed_plan(30.0)
    r = drac(inputs(b, xy, v))
    assert r.max_drac_mps2[0] == 0.0 and r.max_drac_step[0] == -1
    b2 = make([VehicleSpec(x0_m=3.0, speed_mps=30.0)])
    assert np.isinf(drac(inputs(b2, xy, v)).max_drac_mps2[0])


def test_rear_ttc_follower_closing_hand_computed() -> None:
    # slot 0: faster car 40 m behind bumper to bumper (centre -44.5 m) at 35 m/s in the ego's lane;
    # slot 1: faster car in the right lane (not following); ego plan 30 m/s.
    b = make([VehicleSpec(x0_m=-44.5, speed_mps=35.0), VehicleSpec(x0_m=-10.0, speed_mps=40.0, lane_offset=-1)])
    xy, v = constant_speed_plan(30.0)
    inp = inputs(b, xy, v)
    r = rear_ttc_1d(inp)
    # step f at t = (f + 1) * 0.04: gap = 40 - 5 t, TTC = gap / 5; minimum at the last step (gap 15 m)
    assert r.ttc_s[0, 0] == pytest.approx((40.0 - 0.2) / 5.0, abs=1e-4)
    assert r.preceding.nbr[0, 0] == 0
    assert (r.min_ttc_s[0], r.min_ttc_step[0], r.min_ttc_nbr[0]) == (pytest.approx(3.0, abs=1e-4), 124, 0)
    assert np.isinf(ttc_1d(inp).min_ttc_s[0])  # nothing ahead: the front TTC cannot see it


def test_rear_ttc_lane_change_in_front_of_faster_car() -> None:
    # faster car in the left lane 44.5 m behind (centre): once the ego is in the left lane (step 50)
    # it follows the ego; gap 40 m - 10 m/s * t (19.6 m at t = 2.04 s: TTC 1.96 s)
    b = make([VehicleSpec(x0_m=-44.5, speed_mps=40.0, lane_offset=1)])
    y = np.where(np.arange(125) >= 50, 3.75, 0.0)
    xy, v = constant_speed_plan(30.0, y_m=y)
    r = rear_ttc_1d(inputs(b, xy, v))
    assert np.isinf(r.ttc_s[0, :50]).all()
    assert r.ttc_s[0, 50] == pytest.approx(1.96, abs=1e-4)
