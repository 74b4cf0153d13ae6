"""The highway-env adapter without highway-env: hand-built recorded states become the scenario a planner sees
(ego frame, back-fill, neighbour choice, HighD lane ids), and an exported episode read back through letspi's
HighD reader and extractor gives the same scenario."""

from __future__ import annotations

import numpy as np
import pytest

from letspi.constants import DT_S, MAX_NEIGHBOURS, N_HISTORY, T0_INDEX
from letspi.highd.io import read_recording, write_recording
from letspi.scenario.extract import extract_windows

pytest.importorskip("letspi_interop", reason="letspi-interop is not installed (pip install -e packages/letspi-interop)")
from letspi_interop.highway_env.scene import (
    EpisodeTracks,
    RoadLayout,
    ScenarioLabel,
    episode_recording,
    plan_to_world,
    resample,
    scenario_view,
)

HZ = 15.0
ROAD = RoadLayout(np.array([-2.0, 2.0, 6.0, 10.0, 14.0]), 30.0)  # highway-v0's 4 lanes: centres y = 0, 4, 8, 12
LABEL = ScenarioLabel("test", 7, "key")


def tracks(states: list[tuple[float, float, float, float]], n_frames: int, ego: int = 0,
           lateral_mps: dict[int, float] | None = None) -> EpisodeTracks:
    """Vehicles (x0, y0, vx, vy) at constant velocity over ``n_frames`` frames at 15 Hz (row = id - 1);
    ``lateral_mps`` overrides vy of some rows from frame 30 on (a lane change)."""
    t = np.arange(n_frames) / HZ
    s = np.asarray(states, dtype=np.float64)
    v = np.repeat(s[:, None, 2:], n_frames, axis=1)
    for row, vy in (lateral_mps or {}).items():
        v[row, 30:, 1] = vy
    xy = s[:, None, :2] + np.concatenate([np.zeros((len(s), 1, 2)), np.cumsum(v[:, :-1], axis=1) / HZ], axis=1)
    n = len(s)
    return EpisodeTracks(t, xy, v, np.zeros((n, n_frames)), np.zeros((n, n_frames), bool), np.arange(1, n + 1),
                         np.full(n, 5.0), np.full(n, 2.0), ego, np.ones(n_frames, bool))


def test_road_layout_gives_highd_lane_ids_and_image_geometry() -> None:
    # upper carriageway mirrored above: markings 2, 6, 10, 14, 18 (lanes 2..5), median 18..21 (lane 6), ours 7..10
    np.testing.assert_allclose(ROAD.upper_markings_image_m, [2, 6, 10, 14, 18])
    np.testing.assert_allclose(ROAD.lower_markings_image_m, [21, 25, 29, 33, 37])
    np.testing.assert_array_equal(ROAD.lane_ids, [7, 8, 9, 10])
    np.testing.assert_array_equal(ROAD.highd_lane_id(np.array([-3.0, 0.0, 4.0, 13.9, 14.5])), [6, 7, 8, 10, 11])
    np.testing.assert_array_equal(ROAD.lane_index(np.array([-3.0, 0.0, 5.9, 13.9, 14.5])), [-1, 0, 1, 3, -1])
    with pytest.raises(ValueError, match="ascending"):
        RoadLayout(np.array([2.0, -2.0]), 30.0)


def test_first_frame_history_is_back_filled_at_constant_velocity() -> None:
    tr = tracks([(200.0, 4.0, 25.0, 0.0), (230.0, 0.0, 20.0, 0.0)], n_frames=1)
    view = scenario_view(tr, ROAD, LABEL)
    k = np.arange(N_HISTORY) - T0_INDEX
    np.testing.assert_allclose(view.ego_xy_m[0, :, 0], 25.0 * k * DT_S, atol=1e-4)
    np.testing.assert_allclose(view.ego_xy_m[0, :, 1], 0.0)
    np.testing.assert_allclose(view.ego_vxy_mps[0], np.tile([25.0, 0.0], (N_HISTORY, 1)))
    # the neighbour, 30 m ahead in the lane to the ego's left (highway-env y 0 < 4): ego frame y = +4
    np.testing.assert_allclose(view.nbr_xy_m[0, 0, T0_INDEX], [30.0, 4.0], atol=1e-5)
    np.testing.assert_allclose(view.nbr_xy_m[0, 0, 0], [30.0 - 20.0 * 74 * DT_S, 4.0], atol=1e-4)  # the frame stays
    assert view.nbr_valid[0, 0].all() and not view.nbr_valid[0, 1:].any()
    assert view.ego_axy_mps2[0].tolist() == [[0.0, 0.0]] * N_HISTORY


def test_view_is_the_extractors_scene_in_the_ego_frame() -> None:
    ego = (200.0, 4.0, 25.0, 0.0)
    others = [(230.0, 0.0, 20.0, 0.0),      # id 2: ahead left, 30.3 m
              (180.0, 8.0, 30.0, 0.0),      # id 3: behind right
              (351.0, 4.0, 25.0, 0.0),      # id 4: 151 m ahead: not visible
              (250.0, 4.0, 25.0, 0.0),      # id 5 and id 6: 50 m ahead / behind, a tie: lower id first
              (150.0, 4.0, 25.0, 0.0)]
    others += [(260.0 + 5.0 * k, 12.0, 25.0, 0.0) for k in range(6)]  # ids 7..12, 60-85 m ahead: 10 visible
    tr = tracks([ego, *others], n_frames=60)
    view = scenario_view(tr, ROAD, LABEL).history()
    now = tr.xy_m[:, -1]
    dist = np.hypot(*(now - now[0]).T)
    visible = [i for i in range(1, len(now)) if dist[i] <= 100.0]
    expected = sorted(visible, key=lambda i: (round(dist[i], 3), i + 1))[:MAX_NEIGHBOURS]
    np.testing.assert_array_equal(view.nbr_id[0], [i + 1 for i in expected])
    assert len(visible) == 10 and 4 not in view.nbr_id[0] and {11, 12}.isdisjoint(view.nbr_id[0])
    assert view.nbr_id[0].tolist().index(5) < view.nbr_id[0].tolist().index(6)
    slot = view.nbr_id[0].tolist().index(3)
    np.testing.assert_allclose(view.nbr_xy_m[0, slot, T0_INDEX], [now[2, 0] - now[0, 0], -(now[2, 1] - now[0, 1])],
                               atol=1e-4)  # 4 m to the ego's right: y = -4
    np.testing.assert_allclose(view.nbr_vxy_mps[0, slot, T0_INDEX], [30.0, 0.0])
    # markings about the ego (y 4): highway-env -2..14 -> ego frame 6..-10, ascending; lanes right to left
    np.testing.assert_allclose(view.marking_y_m[0], [-10, -6, -2, 2, 6])
    np.testing.assert_array_equal(view.marking_is_edge[0], [True, False, False, False, True])
    np.testing.assert_array_equal(view.lane_ids[0], [10, 9, 8, 7])
    assert view.ego_lane_id[0, T0_INDEX] == 8 and view.nbr_lane_id[0, slot, T0_INDEX] == 9
    assert view.driving_direction[0] == 2 and view.speed_limit_mps[0] == 30.0
    assert view.scenario_id[0] == "test_f98" and view.frame0[0] == 98  # frame 59 at 15 Hz: 3.93 s = 25 Hz frame 98


def test_plans_go_back_to_highway_env_coordinates() -> None:
    xy, vxy = plan_to_world(np.array([[1.0, 2.0]]), np.array([[25.0, 1.0]]), np.array([100.0, 4.0]))
    np.testing.assert_allclose(xy, [[101.0, 2.0]])  # 2 m to the left = smaller highway-env y
    np.testing.assert_allclose(vxy, [[25.0, -1.0]])


def test_resample_interpolates_between_frames_and_holds_after_the_last() -> None:
    t = np.array([0.0, 0.1, 0.2])
    xy = np.array([[[0.0, 0.0], [1.0, 0.0], [3.0, 0.0]]])
    v = np.array([[[10.0, 0.0], [10.0, 0.0], [20.0, 0.0]]])
    pos, vel = resample(t, xy, v, np.array([-0.1, 0.05, 0.15, 0.3]))
    np.testing.assert_allclose(pos[0, :, 0], [-1.0, 0.5, 2.0, 3.0])
    np.testing.assert_allclose(vel[0, :, 0], [10.0, 10.0, 15.0, 20.0])


def test_an_exported_episode_reads_back_as_the_same_scenario(tmp_path) -> None:
    ego = (200.0, 4.0, 25.0, 0.0)
    others = [(230.0, 0.0, 20.0, 0.0), (170.0, 8.0, 30.0, 0.0), (260.0, 4.0, 22.0, 0.0), (120.0, 12.0, 31.0, 0.0)]
    tr = tracks([ego, *others], n_frames=181, lateral_mps={1: 0.8, 0: -0.3})  # two lane drifts from 2 s on
    rec = episode_recording(tr, ROAD, recording_id=3)
    write_recording(rec, tmp_path)
    back = read_recording(tmp_path, 3)
    assert set(back.tracks_meta["id"]) == {1, 2, 3, 4, 5} and back.frame_rate_hz == 25
    assert (back.tracks_meta["drivingDirection"] == 2).all() and (back.tracks_meta["class"] == "Car").all()
    now_frame = 90  # 6.0 s at 15 Hz = 25 Hz frame index 150 (HighD frame 151)
    view = scenario_view(tr.upto(now_frame + 1), ROAD, LABEL)
    window = extract_windows(back, np.array([1]), np.array([151 - T0_INDEX]))
    hist = window.history()
    np.testing.assert_array_equal(hist.nbr_id, view.nbr_id)
    np.testing.assert_allclose(hist.ego_xy_m, view.ego_xy_m, atol=0.02)  # the CSV's 1 cm
    np.testing.assert_allclose(hist.ego_vxy_mps, view.ego_vxy_mps, atol=0.01)
    np.testing.assert_allclose(hist.nbr_xy_m, view.nbr_xy_m, atol=0.02)
    np.testing.assert_allclose(hist.marking_y_m, view.marking_y_m, atol=0.02)
    np.testing.assert_array_equal(hist.lane_ids, view.lane_ids)
    np.testing.assert_array_equal(hist.ego_lane_id, view.ego_lane_id)
    np.testing.assert_array_equal(hist.nbr_lane_id, view.nbr_lane_id)
