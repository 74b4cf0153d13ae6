"""Per-episode metrics (``letspi.metrics.episode``) on hand-built episodes: success, survival, fault, speed,
lane changes, hard brakes, jerk; and the registry the tables derive from."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from letspi.metrics.episode import EPISODE_COLUMNS, EPISODE_METRICS, EpisodeInputs, episode_metrics, reference_markdown

HZ = 15.0
DT = 1.0 / HZ


def episode(xy: np.ndarray, vxy: np.ndarray, crashed: np.ndarray | None = None, on_road: np.ndarray | None = None,
            lane: np.ndarray | None = None, latency: tuple[float, ...] = ()) -> EpisodeInputs:
    """(V, T, 2) states at 15 Hz, ego row 0, every vehicle 5 x 2 m."""
    v, t = xy.shape[:2]
    return EpisodeInputs(np.arange(t) * DT, xy, vxy, np.full(v, 5.0), np.full(v, 2.0), 0,
                         np.zeros((v, t), bool) if crashed is None else crashed,
                         np.ones(t, bool) if on_road is None else on_road,
                         np.zeros(t, int) if lane is None else lane, np.asarray(latency, dtype=float))


def straight(x0: float, y0: float, speed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A track (T, 2) along x from (x0, y0) with the given speeds (T,), integrated at 15 Hz."""
    x = x0 + np.concatenate([[0.0], np.cumsum(speed[:-1]) * DT])
    return np.stack([x, np.full_like(x, y0)], 1), np.stack([speed, np.zeros_like(speed)], 1)


def test_running_into_a_stopped_car_is_an_at_fault_collision() -> None:
    t = 60
    ego_xy, ego_v = straight(0.0, 0.0, np.full(t, 20.0))
    car_xy, car_v = straight(50.0, 0.0, np.zeros(t))
    contact = int(np.argmax(car_xy[:, 0] - ego_xy[:, 0] < 5.0))  # bumpers meet: centres 5 m apart
    crashed = np.zeros((2, t), bool)
    crashed[:, contact:] = True
    m = episode_metrics(episode(np.stack([ego_xy, car_xy]), np.stack([ego_v, car_v]), crashed, latency=(0.01, 0.03)))
    assert contact == 34 and m["collision"] and m["at_fault"] and not m["success"] and not m["off_road"]
    assert m["survival_s"] == pytest.approx(contact * DT) and m["episode_s"] == pytest.approx((t - 1) * DT)
    assert m["distance_m"] == pytest.approx(20.0 * contact * DT) and m["mean_speed_mps"] == pytest.approx(20.0)
    assert m["min_ttc_s"] == 0.0 and m["lane_changes_n"] == 0 and m["hard_brakes_n"] == 0
    assert m["planner_latency_s"] == pytest.approx(0.02) and m["planner_latency_max_s"] == pytest.approx(0.03)


def test_a_car_cutting_into_the_ego_is_not_its_fault() -> None:
    t = 45
    ego_xy, ego_v = straight(0.0, 0.0, np.full(t, 25.0))
    car_xy, car_v = straight(8.0, -4.0, np.full(t, 25.0))  # alongside-ahead, in the lane to the right (y -4)
    lateral = np.clip((np.arange(t) - 30) * 0.4, 0.0, 4.0)  # swerves left at 6 m/s from frame 30
    car_xy[:, 1] += lateral
    car_v[:, 1] = np.gradient(lateral, DT)
    contact = int(np.argmax(np.abs(car_xy[:, 1]) < 2.0))
    crashed = np.zeros((2, t), bool)
    crashed[:, contact:] = True
    m = episode_metrics(episode(np.stack([ego_xy, car_xy]), np.stack([ego_v, car_v]), crashed))
    assert m["collision"] and not m["at_fault"] and m["survival_s"] == pytest.approx(contact * DT)


def test_a_clean_episode_counts_lane_changes_hard_brakes_and_jerk() -> None:
    t = 150
    speed = np.full(t, 25.0)
    speed[30:45] = 25.0 - 5.0 * DT * np.arange(1, 16)  # 1 s at -5 m/s^2, to 20
    speed[45:] = 20.0
    speed[90:98] = 20.0 - 6.0 * DT * np.arange(1, 9)  # about 0.5 s at -6 m/s^2, then steady
    speed[98:] = speed[97]
    ego_xy, ego_v = straight(0.0, 0.0, speed)
    car_xy, car_v = straight(200.0, 0.0, np.full(t, 30.0))
    lane = np.repeat([1, 2, 2, 1, 1], 30)
    m = episode_metrics(episode(np.stack([ego_xy, car_xy]), np.stack([ego_v, car_v]), lane=lane))
    assert m["success"] and not m["collision"] and not m["at_fault"] and m["survival_s"] == pytest.approx(149 * DT)
    assert m["lane_changes_n"] == 2 and m["hard_brakes_n"] == 2
    assert m["peak_jerk_mps3"] == pytest.approx(6.0 * HZ)  # the step from -6 m/s^2 to 0 in one frame
    assert m["mean_speed_mps"] == pytest.approx(speed.mean())
    assert m["min_ttc_s"] == np.inf and np.isnan(m["planner_latency_s"])  # never closing; no plans


def test_leaving_the_road_ends_the_success_there() -> None:
    t = 30
    ego_xy, ego_v = straight(0.0, 0.0, np.full(t, 20.0))
    on_road = np.arange(t) < 12
    m = episode_metrics(episode(ego_xy[None], ego_v[None], on_road=on_road))
    assert m["off_road"] and not m["success"] and not m["collision"]
    assert m["survival_s"] == pytest.approx(12 * DT) and m["distance_m"] == pytest.approx(20.0 * 12 * DT)


def test_the_registry_declares_every_value_once_with_its_unit() -> None:
    values = episode_metrics(episode(*[a[None] for a in straight(0.0, 0.0, np.full(10, 20.0))]))
    assert tuple(values) == EPISODE_COLUMNS
    keys = [a.key for m in EPISODE_METRICS for a in m.aggregates]
    assert len(keys) == len(set(keys))
    for m in EPISODE_METRICS:
        assert m.dtype == "bool" or m.name.endswith(("_s", "_m", "_mps", "_mps3", "_n")), m.name


def test_the_docs_reference_is_generated_from_the_registry() -> None:
    text = (Path(__file__).resolve().parents[1] / "docs" / "highway-env.md").read_text(encoding="utf-8")
    block = text.split("<!-- generated below: letspi.metrics.episode.reference_markdown() -->\n\n")[1]
    assert block.split("\n<!-- generated above -->")[0] == reference_markdown(), (
        "docs/highway-env.md's metric reference is stale: paste letspi.metrics.episode.reference_markdown()")
