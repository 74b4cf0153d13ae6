"""The highway-env side of the bridge, in highway-env itself: the ego tracks a plan, a seed gives the same scene
whichever ego is swapped in, IDM followers react to the ego, bad ids and keys fail in one line.
Skipped without the ``highway`` extra."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

pytest.importorskip("highway_env", reason="the highway extra of letspi-interop is not installed")
from highway_env.vehicle.behavior import IDMVehicle

pytest.importorskip("letspi_interop", reason="letspi-interop is not installed (pip install -e packages/letspi-interop)")
import letspi_interop.highway_env as bridge
from letspi_interop.highway_env import sim

HZ = 15
EMPTY = {"lanes_count": 4, "vehicles_count": 0, "initial_lane_id": 1, "simulation_frequency": HZ,
         "policy_frequency": 5, "duration": 30}
DILU = {"lanes_count": 4, "vehicles_count": 50, "vehicles_density": 2, "ego_spacing": 4, "simulation_frequency": HZ,
        "policy_frequency": 5, "duration": 30}


def _quintic(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return 10 * u**3 - 15 * u**4 + 6 * u**5


def plan_from(x0: float, y0: float, speed_of_t, y_of_t, horizon_s: float = 8.0) -> sim.Plan:
    """A plan at 25 Hz from t = 0: speed and lateral position as functions of time (highway-env coordinates)."""
    t = np.arange(int(horizon_s * 25) + 1) / 25.0
    v = speed_of_t(t)
    x = x0 + np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    y = y_of_t(t)
    return sim.Plan(t, np.stack([x, y], axis=1), np.stack([v, np.gradient(y, t)], axis=1))


def empty_road(seed: int = 0, **extra):
    env = sim.make_env("highway-v0", {**EMPTY, **extra})
    env.reset(seed=seed)
    return env


def drive(env, ego, plan: sim.Plan, seconds: float) -> sim.Recorder:
    recorder = sim.Recorder(env, int(seconds * HZ) + 1)
    ego.follow(plan)
    for _ in range(int(seconds * 5)):
        sim.advance(env, recorder, HZ // 5)
    return recorder


def test_the_ego_tracks_a_lane_change_while_braking() -> None:
    env = empty_road()
    ego = sim.install_ego(env, "plan")
    assert isinstance(ego, sim.TrackingEgo) and ego.position[1] == pytest.approx(4.0) and ego.speed == 25.0
    x0 = float(ego.position[0])
    plan = plan_from(x0, 4.0, lambda t: np.maximum(25.0 - 1.0 * t, 20.0), lambda t: 4.0 + 4.0 * _quintic((t - 1) / 4))
    lanes_targeted = []
    recorder = sim.Recorder(env, 6 * HZ + 1)
    ego.follow(plan)
    for _ in range(30):
        sim.advance(env, recorder, 3)
        lanes_targeted.append(ego.target_lane_index[2])
    tr = recorder.tracks()
    want_xy = np.array([plan.at(t)[0] for t in tr.t_s])
    err = tr.xy_m[0] - np.array(want_xy)
    assert np.abs(err[:, 0]).max() < 0.3 and np.abs(err[:, 1]).max() < 0.25  # metres, at every frame
    assert abs(tr.xy_m[0, -1, 1] - 8.0) < 0.1 and abs(np.hypot(*tr.vxy_mps[0, -1]) - 20.0) < 0.2
    assert lanes_targeted[0] == 1 and lanes_targeted[-1] == 2  # the target lane leads the lane change
    assert lanes_targeted.index(2) < int(np.argmax(tr.xy_m[0, :, 1] > 6.0)) / 3  # ... before the centre crosses
    assert ego.target_speed == pytest.approx(20.0, abs=0.01)


def test_the_ego_brakes_and_steers_no_harder_than_a_car() -> None:
    env = empty_road()
    ego = sim.install_ego(env, "plan")
    x0 = float(ego.position[0])
    plan = plan_from(x0, 4.0, lambda t: np.maximum(25.0 - 30.0 * t, 0.0), lambda t: np.where(t > 0.2, 12.0, 4.0))
    tr = drive(env, ego, plan, 2.0).tracks()
    acc = np.diff(np.hypot(*tr.vxy_mps[0].T)) * HZ
    assert acc.min() >= -sim.TrackingEgo.DECEL_MAX_MPS2 - 1e-6 and acc.min() < -7.9
    heading_rate = np.diff(tr.heading_rad[0]) * HZ
    lateral_acc = np.hypot(*tr.vxy_mps[0, 1:].T) * np.abs(heading_rate)
    assert lateral_acc.max() <= sim.TrackingEgo.LAT_ACC_MAX_MPS2 * 1.05


def test_a_seed_gives_the_same_scene_whichever_ego_is_swapped_in() -> None:
    def scene(kind: str | None) -> tuple[np.ndarray, object]:
        env = sim.make_env("highway-v0", DILU)
        env.reset(seed=5838)
        if kind is not None:
            sim.install_ego(env, kind)
        return np.array([v.position for v in env.road.vehicles]), env.np_random.bit_generator.state

    base, state = scene(None)
    assert base.shape == (51, 2)
    for kind in sim.EGO_KINDS:
        positions, after = scene(kind)
        np.testing.assert_array_equal(positions, base)
        assert after == state  # no random number drawn by the swap
    other, _ = scene(None)
    np.testing.assert_array_equal(other, base)
    env = sim.make_env("highway-v0", DILU)
    env.reset(seed=2421)
    assert not np.array_equal(np.array([v.position for v in env.road.vehicles]), base)


def test_two_runs_of_a_seed_give_identical_tracks() -> None:
    def run() -> np.ndarray:
        env = sim.make_env("highway-v0", DILU)
        env.reset(seed=7294)
        ego = sim.install_ego(env, "plan")
        x0, y0 = ego.position
        plan = plan_from(float(x0), float(y0), lambda t: np.full_like(t, 24.0), lambda t: np.full_like(t, y0))
        return drive(env, ego, plan, 3.0).tracks().xy_m

    np.testing.assert_array_equal(run(), run())


def test_an_idm_follower_brakes_for_a_braking_ego() -> None:
    def follower_speeds(brake: bool) -> np.ndarray:
        env = empty_road()
        ego = sim.install_ego(env, "plan")
        x0 = float(ego.position[0])
        follower = IDMVehicle(env.road, [x0 - 30.0, 4.0], 0.0, 25.0, target_speed=25.0, enable_lane_change=False)
        env.road.vehicles.append(follower)
        speed = (lambda t: np.maximum(25.0 - 4.0 * t, 10.0)) if brake else (lambda t: np.full_like(t, 25.0))
        tr = drive(env, ego, plan_from(x0, 4.0, speed, lambda t: np.full_like(t, 4.0)), 6.0).tracks()
        assert not tr.crashed.any()
        return np.hypot(*tr.vxy_mps[1].T)

    calm, braking = follower_speeds(False), follower_speeds(True)
    assert calm[-1] > 21.0  # settles at its desired gap behind a steady ego
    assert braking[-1] < 13.0 and braking[-1] < calm[-1] - 8.0  # follows the ego down to 10 m/s


def test_an_idm_ego_and_a_lane_keeper_drive_themselves() -> None:
    env = sim.make_env("highway-v0", DILU)
    env.reset(seed=5838)
    keeper = sim.install_ego(env, "lane-keeper")
    recorder = sim.Recorder(env, 30 * HZ + 1)
    while not sim.ended(env):
        sim.advance(env, recorder, 3)
    tr = recorder.tracks()
    assert tr.crashed[tr.ego, -1] and np.allclose(np.hypot(*tr.vxy_mps[tr.ego, :-2].T), 25.0)  # no car following
    assert np.ptp(tr.xy_m[tr.ego, :, 1]) < 1e-9 and keeper.speed < 25.0
    env.reset(seed=5838)
    idm = sim.install_ego(env, "idm")
    assert isinstance(idm, IDMVehicle) and idm.target_speed == 30.0  # the road's limit


def test_bad_environments_and_keys_fail_in_one_line(monkeypatch) -> None:
    with pytest.raises(sim.HighwayEnvSetupError, match=r"unknown highway-env environment 'parking-v0': letspi drives"):
        sim.make_env("parking-v0", {})
    with pytest.raises(sim.HighwayEnvSetupError, match=r"highway-v0 has no configuration key 'lane_count'"):
        sim.make_env("highway-v0", {"lane_count": 4})
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "highway_env" else real(name))
    with pytest.raises(bridge.HighwayEnvMissingError) as err:
        bridge.require()
    assert str(err.value) == 'highway_env not installed: pip install -e "packages/letspi-interop[highway]"'


def test_road_layout_and_recorder_of_merge_v0() -> None:
    env = sim.make_env("merge-v0", {"simulation_frequency": HZ, "policy_frequency": 5})
    env.reset(seed=1)
    road = sim.road_layout(env)
    np.testing.assert_allclose(road.markings_y_m, [-2.0, 2.0, 6.0])  # the two main lanes; the ramp is off the road
    assert road.speed_limit_mps == 20.0
    ego = sim.install_ego(env, "idm")
    recorder = sim.Recorder(env, 40 * HZ)
    while not sim.ended(env):
        sim.advance(env, recorder, 3)
    tr = recorder.tracks()
    assert tr.xy_m[tr.ego, -1, 0] > 370 or ego.crashed  # merge-v0 ends once the ramp is passed
    np.testing.assert_allclose(np.diff(tr.t_s), 1.0 / HZ)
