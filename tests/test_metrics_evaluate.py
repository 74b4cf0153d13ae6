"""compute_metrics end to end: kinematics, success, argmin fields, aggregation of infinities."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from test_metrics_helpers import T_FUT, constant_speed_plan, make

from letspi.constants import T0_INDEX
from letspi.metrics import (
    MetricsConfig,
    aggregate_metrics,
    compute_metrics,
    finite_mean,
    human_future,
    render_markdown_table,
)
from letspi.metrics.aggregate import TABLE_COLUMNS
from letspi.metrics.kinematics import count_lane_changes, lane_index
from letspi.scenario.build import VehicleSpec
from letspi.scenario.types import concat_batches

SAFE = [
    VehicleSpec(x0_m=40.0, speed_mps=30.0),
    VehicleSpec(x0_m=-30.0, speed_mps=30.0),
    VehicleSpec(x0_m=5.0, speed_mps=28.0, lane_offset=1),
]


def test_human_ground_truth_is_collision_free_and_successful() -> None:
    b = make(SAFE)
    xy, v = human_future(b)
    m = compute_metrics(b, xy, v, goals_xy_m=xy[:, -1])
    assert not m.collision[0] and not m.collision_2m[0] and not m.off_road[0]
    assert m.success[0] and m.ade_m[0] == 0.0 and m.fde_m[0] == 0.0
    assert np.isinf(m.min_ttc_s[0])  # same speed as the leader: never closing
    assert m.min_box_gap_m[0] == pytest.approx(3.75 - 1.8, abs=1e-4)  # the car alongside
    assert m.min_gap_nbr[0] == 2
    assert m.peak_abs_acc_lon_mps2[0] == 0.0 and m.n_lane_changes[0] == 0


def test_success_false_for_off_road_plan() -> None:
    b = make(SAFE, ego_lane_index=0)  # rightmost lane: right edge at y = -1.875
    xy, v = constant_speed_plan(30.0, y_m=-1.5)  # box reaches y = -2.4
    m = compute_metrics(b, xy, v, goals_xy_m=xy[:, -1])
    assert m.off_road[0] and not m.collision[0] and not m.success[0]
    xy_ok, v_ok = constant_speed_plan(30.0, y_m=-0.5)
    assert compute_metrics(b, xy_ok, v_ok, goals_xy_m=xy_ok[:, -1]).success[0]


def test_success_false_for_colliding_plan_and_argmin_fields() -> None:
    b = make([VehicleSpec(x0_m=0.0, speed_mps=30.0, lane_offset=1), VehicleSpec(x0_m=24.6, speed_mps=25.0)])
    xy, v = constant_speed_plan(30.0)
    m = compute_metrics(b, xy, v, goals_xy_m=xy[:, -1])
    assert m.collision[0] and not m.success[0] and m.finite[0] and m.feasible[0] and m.goal_reached[0]
    assert (m.collision_step[0], m.collision_nbr[0]) == (100, 1)
    assert (m.min_ttc_s[0], m.min_ttc_step[0], m.min_ttc_nbr[0]) == (0.0, 100, 1)
    assert m.low_ttc[0]
    assert m.min_gap_nbr[0] == 1 and m.min_box_gap_m[0] == 0.0 and m.min_gap_step[0] == 100


def test_self_goal_tolerance_and_non_finite() -> None:
    b = make(SAFE)
    xy, v = constant_speed_plan(30.0)
    goal = xy[:, -1] + np.array([[4.0, 0.9]])
    assert compute_metrics(b, xy, v, goals_xy_m=goal).success_self[0]
    far = xy[:, -1] + np.array([[6.0, 0.0]])
    m_far = compute_metrics(b, xy, v, goals_xy_m=far)
    assert not m_far.goal_reached[0] and not m_far.success_self[0]
    assert m_far.success[0]  # the headline SR does not depend on the planner's own goal
    cfg = MetricsConfig(goal_tol_lon_m=7.0)
    assert compute_metrics(b, xy, v, goals_xy_m=far, config=cfg).success_self[0]
    bad = xy.copy()
    bad[0, 10, 0] = np.nan
    m = compute_metrics(b, bad, v, goals_xy_m=goal)
    assert not m.finite[0] and not m.success[0] and not m.success_self[0]


def _shortened_plan(fraction_short: float) -> tuple[np.ndarray, np.ndarray]:
    """From 30 m/s at t = 0, constant braking so that 5 s progress is (1 - fraction_short) x 150 m."""
    t_end = T_FUT[-1]
    decel = 2.0 * fraction_short * 30.0 * t_end / t_end**2
    x = 30.0 * T_FUT - 0.5 * decel * T_FUT**2
    return np.stack([x, np.zeros_like(x)], -1)[None], np.stack([30.0 - decel * T_FUT, np.zeros_like(x)], -1)[None]


# the human keeps its lane at 30 m/s (150 m in 5 s) behind a leader 40 m ahead at the same speed
FOLLOWING = [VehicleSpec(x0_m=40.0, speed_mps=30.0)]


def test_sr_human_future_passes() -> None:
    b = make(FOLLOWING)
    hxy, hv = human_future(b)
    human = compute_metrics(b, hxy, hv, goals_xy_m=hxy[:, -1])
    assert human.success[0] and human.reference_reached[0] and human.success_self[0]


def test_sr_plan_stopping_30_percent_short_fails() -> None:
    # braking at 3.6 m/s^2 (feasible) ends 105 m on instead of 150 m: SR fails although the planner
    # reached its own (shortened) goal; 5 % short (7.5 m) is within the 10 % (15 m) tolerance
    b = make(FOLLOWING)
    xy, v = _shortened_plan(0.30)
    assert xy[0, -1, 0] == pytest.approx(105.0)
    short = compute_metrics(b, xy, v, goals_xy_m=xy[:, -1])
    assert not short.success[0]
    assert short.feasible[0] and not short.collision[0] and short.success_self[0]
    assert not short.reference_reached[0]
    assert compute_metrics(b, *_shortened_plan(0.05)).success[0]


def test_sr_plan_ending_one_lane_off_fails() -> None:
    # a cosine lane change to the left over 3 s (peak a_lat 2.1 m/s^2, nothing in the way), with the
    # planner's own goal there
    b = make(FOLLOWING)
    u = np.clip((T_FUT - 1.0) / 3.0, 0.0, 1.0)
    y = 3.75 * 0.5 * (1.0 - np.cos(np.pi * u))
    lxy, lv = constant_speed_plan(30.0, y_m=y)
    lv[0, :, 1] = 3.75 * 0.5 * np.pi / 3.0 * np.sin(np.pi * u)
    lane = compute_metrics(b, lxy, lv, goals_xy_m=lxy[:, -1])
    assert lane.feasible[0] and not lane.collision[0] and not lane.off_road[0] and lane.goal_reached[0]
    assert not lane.success[0]
    assert lane.success_self[0] and not lane.reference_reached[0]
    agg = aggregate_metrics(lane)
    assert agg["sr_pct"] == 0.0 and agg["sr_self_pct"] == 100.0


def test_reference_lane_accepts_a_human_ending_on_a_marking() -> None:
    # the human ends mid lane change just across the marking at y = 1.875 m (y = 1.95 m, left lane):
    # a plan ending 0.4 m right of it (in the ego's lane) passes by the lateral tolerance, 0.6 m does not
    b = make([])
    b.ego_xy_m[0, T0_INDEX + 1 :, 1] = np.linspace(0.0, 1.95, 125)
    for dy, ok in ((0.4, True), (0.6, False)):
        xy, v = constant_speed_plan(30.0, y_m=np.linspace(0.0, 1.95 - dy, 125))
        v[0, :, 1] = (1.95 - dy) / (124 * 0.04)
        assert compute_metrics(b, xy, v).reference_reached[0] == ok


def test_kinematics_ade_fde_acceleration_jerk() -> None:
    # the human brakes at 2 m/s^2 from 30 m/s; the plan copies it, shifted by (0.3, 0.4) m
    b = make(SAFE, ego_accel_mps2=-2.0)
    hxy, hv = human_future(b)
    m = compute_metrics(b, hxy + np.array([0.3, 0.4]), hv)
    assert m.ade_m[0] == pytest.approx(0.5, abs=1e-5) and m.fde_m[0] == pytest.approx(0.5, abs=1e-5)
    assert m.peak_abs_acc_lon_mps2[0] == pytest.approx(2.0, abs=1e-3)
    assert m.peak_abs_jerk_mps3[0] == pytest.approx(0.0, abs=1e-2)  # a(t=0) = -2 already
    # from a scenario whose ego was cruising at t = 0, the same plan starts with a jerk of 2 / 0.04
    b0 = make(SAFE)
    v_brake = np.stack([30.0 - 2.0 * T_FUT, np.zeros_like(T_FUT)], -1)[None]
    m0 = compute_metrics(b0, human_future(b0)[0], v_brake)
    assert m0.peak_abs_jerk_mps3[0] == pytest.approx(50.0, rel=1e-4)


def test_infeasible_acceleration_fails_success() -> None:
    b = make(SAFE)
    xy, v = constant_speed_plan(30.0)
    v = v.copy()
    v[0, 60:, 0] -= 0.5  # a 0.5 m/s drop in one frame = 12.5 m/s^2
    m = compute_metrics(b, xy, v, goals_xy_m=xy[:, -1])
    assert m.peak_abs_acc_lon_mps2[0] == pytest.approx(12.5) and not m.feasible[0] and not m.success[0]


def test_lane_changes_counted_from_markings() -> None:
    marks = np.array([[-5.625, -1.875, 1.875, 5.625]])
    assert lane_index(np.array([[-3.0, 0.0, 3.0, 7.0]]), marks).tolist() == [[0, 1, 2, 3]]
    f = np.arange(125)
    there = 3.75 * np.clip((f - 20) / 50.0, 0, 1)[None]
    back = 3.75 * np.sin(np.pi * f / 124.0)[None]
    assert count_lane_changes(np.zeros(1), there, marks)[0] == 1
    assert count_lane_changes(np.zeros(1), back, marks)[0] == 2


def test_compute_metrics_vectorised_over_batch_and_chunks() -> None:
    b = concat_batches([make(SAFE), make([VehicleSpec(x0_m=24.6, speed_mps=25.0)]), make([])])
    xy, v = constant_speed_plan(30.0)
    xy3, v3 = np.repeat(xy, 3, 0), np.repeat(v, 3, 0)
    whole = compute_metrics(b, xy3, v3).to_frame()
    chunked = compute_metrics(b, xy3, v3, config=MetricsConfig(chunk_size=2)).to_frame()
    assert whole.equals(chunked)
    assert whole["collision"].tolist() == [False, True, False]
    assert math.isinf(whole.loc[2, "min_centre_dist_m"]) and whole.loc[2, "min_gap_nbr"] == -1
    assert len(whole.columns) == len(set(whole.columns)) and "min_ttc2d_s" in whole


def test_aggregate_infinite_values() -> None:
    b = concat_batches([make(SAFE)] * 4)
    xy, v = constant_speed_plan(30.0)
    df = compute_metrics(b, np.repeat(xy, 4, 0), np.repeat(v, 4, 0)).to_frame()
    df["min_ttc_s"] = [np.inf, 1.0, 4.0, np.inf]
    df["low_ttc"] = df["min_ttc_s"] < 2.0
    df["min_pet_s"] = [np.inf, np.inf, np.inf, np.inf]
    df["collision"] = [True, False, False, False]
    df["success"] = [False, True, True, True]
    agg = aggregate_metrics(df, inference_time_s=[0.1, 0.3, np.nan, 0.2])
    assert agg["n"] == 4
    # capped mean over all scenarios: inf -> 10 s cap; finite-only mean kept beside it
    assert agg["ttc_s"] == pytest.approx((10.0 + 1.0 + 4.0 + 10.0) / 4) and agg["ttc_finite_n"] == 2
    assert agg["ttc_finite_mean_s"] == pytest.approx(2.5) and agg["ttc_capped_n"] == 2
    assert aggregate_metrics(df, config=MetricsConfig(ttc_cap_s=3.0))["ttc_s"] == pytest.approx(2.5)
    assert agg["lt_pct"] == pytest.approx(25.0) and agg["cr_pct"] == pytest.approx(25.0)
    assert agg["sr_pct"] == pytest.approx(75.0)
    assert agg["pet_s"] is None and agg["pet_finite_n"] == 0
    assert agg["inference_s"] == pytest.approx(0.2)
    for key in ("n", "ttc_s", "cr_pct", "pet_s", "min_dist_m", "lt_pct", "sr_pct", "inference_s"):
        assert key in agg
    # strict JSON: no NaN / inf anywhere
    json.dumps(agg, allow_nan=False)
    assert finite_mean(np.array([np.inf, -np.inf, np.nan])) == (None, 0)
    df["inference_s"] = 0.5  # the evaluation harness stores per-scenario times in the frame
    assert aggregate_metrics(df)["inference_s"] == pytest.approx(0.5)
    assert aggregate_metrics(df.drop(columns="inference_s"))["inference_s"] is None


def test_render_markdown_table() -> None:
    b = make(SAFE)
    xy, v = human_future(b)
    agg = aggregate_metrics(compute_metrics(b, xy, v), inference_time_s=0.1)
    md = render_markdown_table({"human": agg, "other": {**agg, "pet_s": None}})
    lines = md.splitlines()
    assert lines[0].startswith(
        "| Model | ↑ TTC (s) | ↓ CR (%) | ↓ CR at fault (%) | ↑ PET (s) | ↑ minD (m) | ↓ LT (%) | ↑ SR (%)"
    )
    assert lines[2].startswith("| human | 10.00 | 0.00 | 0.00 |") and "| 0.10 |" in lines[2]
    assert len(lines[3].split("|")) == len(TABLE_COLUMNS) + 3 and "n/a" in lines[3]
    assert "TTC 0/1" in md
