"""highway-env's side of the bridge: environments, the egos, the recorder (imports highway-env at module level).

``make_env`` (headless; unknown ids or configuration keys refused in one line), ``road_layout``, the egos
swapped in after ``reset`` without drawing a random number (``install_ego``: a seed gives the same scene
whichever ego drives) -- ``TrackingEgo`` (follows letspi's plan at every simulation frame), ``"idm"``
(highway-env's IDM and MOBIL), ``"lane-keeper"`` -- the ``Recorder`` of every vehicle's state, and
``advance`` (one policy period of highway-env's own loop, timed). The tracking controller's laws and
limits: notes/rationale-runtime-evaluation.md, "highway-env egos".
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final, Literal

import gymnasium
import highway_env  # noqa: F401  (registers the environments)
import numpy as np
from gymnasium.envs.registration import load_env_creator
from highway_env import utils
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.road.lane import StraightLane
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle
from highway_env.vehicle.kinematics import Vehicle

from letspi_interop.highway_env.scene import EpisodeTracks, RoadLayout

#: environments letspi drives: straight roads along x (HighD's geometry)
ENV_IDS: Final = ("highway-v0", "highway-fast-v0", "merge-v0")
EgoKind = Literal["plan", "idm", "lane-keeper"]
EGO_KINDS: Final = ("plan", "idm", "lane-keeper")
#: a road heading further from x than this is not "along x" [rad]
STRAIGHT_TOL_RAD: Final = 1e-6


class HighwayEnvSetupError(ValueError):
    """An environment id, configuration key or road letspi cannot drive (the message names the fix)."""


def env_class(env_id: str) -> type[AbstractEnv]:
    """The environment class registered under ``env_id`` (one of ``ENV_IDS``)."""
    if env_id not in ENV_IDS:
        raise HighwayEnvSetupError(f"unknown highway-env environment {env_id!r}: letspi drives {', '.join(ENV_IDS)}")
    creator = load_env_creator(gymnasium.spec(env_id).entry_point)  # type: ignore[arg-type]
    assert isinstance(creator, type) and issubclass(creator, AbstractEnv), creator
    return creator


def check_config(env_id: str, config: Mapping[str, Any]) -> dict[str, Any]:
    """``config`` if every key is one of the environment's (``default_config``), else one line naming the key."""
    known = env_class(env_id).default_config()
    unknown = sorted(set(config) - set(known))
    if unknown:
        raise HighwayEnvSetupError(f"{env_id} has no configuration key {', '.join(map(repr, unknown))}; its keys: "
                                   f"{', '.join(sorted(known))}")
    return dict(config)


def make_env(env_id: str, config: Mapping[str, Any]) -> AbstractEnv:
    """The environment (unwrapped), headless, with ``config`` over its defaults (checked: ``check_config``)."""
    with warnings.catch_warnings():  # merge-v0 is pinned on purpose (docs/highway-env.md): no warning per episode
        warnings.filterwarnings("ignore", message=".*is out of date", category=DeprecationWarning)
        env = gymnasium.make(env_id, config=check_config(env_id, config), render_mode=None, disable_env_checker=True)
    unwrapped = env.unwrapped
    assert isinstance(unwrapped, AbstractEnv)
    return unwrapped


def road_layout(env: AbstractEnv) -> RoadLayout:
    """The carriageway of the ego's road segment after ``reset``: its straight lanes along x."""
    network = env.road.network
    _from, _to, _ = env.vehicle.lane_index
    lanes = network.graph[_from][_to]
    if not all(isinstance(lane, StraightLane) and abs(utils.wrap_to_pi(lane.heading)) < STRAIGHT_TOL_RAD
               for lane in lanes):
        raise HighwayEnvSetupError(f"{type(env).__name__}: the ego's road {_from}->{_to} is not straight along x; "
                                   f"letspi drives {', '.join(ENV_IDS)}")
    centres = np.array([lane.start[1] for lane in lanes], dtype=np.float64)
    widths = np.array([lane.width for lane in lanes], dtype=np.float64)
    order = np.argsort(centres)
    edges = np.concatenate([centres[order] - widths[order] / 2, centres[order][-1:] + widths[order][-1:] / 2])
    limit = lanes[0].speed_limit
    return RoadLayout(edges, float(limit) if limit is not None else float("nan"))


@dataclass
class Plan:
    """A plan the ego follows, in highway-env coordinates: t_s (K,) simulation times, ascending (the first is
    the instant it was made, with the ego's state then); xy_m, vxy_mps (K, 2)."""

    t_s: np.ndarray
    xy_m: np.ndarray
    vxy_mps: np.ndarray

    def at(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity (2,) each at ``t_s`` (linear; the ends held outside the plan)."""
        pos = np.array([np.interp(t_s, self.t_s, self.xy_m[:, k]) for k in range(2)])
        vel = np.array([np.interp(t_s, self.t_s, self.vxy_mps[:, k]) for k in range(2)])
        return pos, vel


class TrackingEgo(ControlledVehicle):  # type: ignore[misc]
    """The ego that follows letspi's plan (module docstring). ``follow(plan)`` replaces the plan; without one it
    keeps its lane and speed as a ``ControlledVehicle``. ``control_s`` sums the wall time of its control."""

    ACC_MAX_MPS2: Final = 5.0
    DECEL_MAX_MPS2: Final = 8.0
    LAT_ACC_MAX_MPS2: Final = 5.0
    #: feedback on the planned speed [1/s] and position [1/s^2]: critically damped at 1.5 rad/s
    KP_SPEED: Final = 3.0
    KP_POSITION: Final = 2.25
    PREVIEW_S: Final = 1.0

    def __init__(self, road: Any, position: Any, heading: float = 0.0, speed: float = 0.0, *,
                 dt_s: float, clock_s: float = 0.0) -> None:
        super().__init__(road, position, heading, speed)
        self.dt_s = float(dt_s)
        self.clock_s = float(clock_s)
        self.plan: Plan | None = None
        self.control_s = 0.0

    def follow(self, plan: Plan) -> None:
        self.plan = plan

    def act(self, action: dict[str, float] | str | None = None) -> None:
        t0 = time.perf_counter()
        if self.plan is None or self.crashed:
            super().act()
        else:
            Vehicle.act(self, self._control(self.plan))
        self.control_s += time.perf_counter() - t0

    def _control(self, plan: Plan) -> dict[str, float]:
        t = self.clock_s
        ref_xy, ref_v = plan.at(t)
        _, next_v = plan.at(t + self.dt_s)
        ahead_xy, ahead_v = plan.at(t + self.PREVIEW_S)
        self.target_speed = float(np.hypot(*ahead_v))
        self.target_lane_index = self.road.network.get_closest_lane_index(ahead_xy, 0.0)
        speed = max(float(self.speed), 1.0)
        acc = ((np.hypot(*next_v) - np.hypot(*ref_v)) / self.dt_s + self.KP_SPEED * (np.hypot(*ref_v) - self.speed)
               + self.KP_POSITION * (ref_xy[0] - self.position[0]))
        lateral_speed = ref_v[1] + self.KP_LATERAL * (ref_xy[1] - self.position[1])
        heading_ref = np.clip(np.arcsin(np.clip(lateral_speed / speed, -1, 1)), -np.pi / 4, np.pi / 4)
        heading_rate = self.KP_HEADING * utils.wrap_to_pi(heading_ref - self.heading)
        max_sin_slip = min(1.0, self.LAT_ACC_MAX_MPS2 * (self.LENGTH / 2) / speed**2)
        slip = np.arcsin(np.clip(self.LENGTH / 2 / speed * heading_rate, -max_sin_slip, max_sin_slip))
        steering = np.clip(np.arctan(2 * np.tan(slip)), -self.MAX_STEERING_ANGLE, self.MAX_STEERING_ANGLE)
        return {"steering": float(steering), "acceleration": float(np.clip(acc, -self.DECEL_MAX_MPS2,
                                                                           self.ACC_MAX_MPS2))}

    def step(self, dt: float) -> None:
        super().step(dt)
        self.clock_s += dt


def install_ego(env: AbstractEnv, kind: EgoKind) -> Vehicle:
    """Replace the environment's ego (after ``reset``) by one of ``EGO_KINDS`` at the same state and place in
    ``road.vehicles``; no random number is drawn."""
    old = env.vehicle
    position, heading, speed = np.array(old.position, dtype=np.float64), float(old.heading), float(old.speed)
    new: Vehicle
    if kind == "plan":
        new = TrackingEgo(env.road, position, heading, speed, dt_s=1.0 / env.config["simulation_frequency"],
                          clock_s=float(env.time))
    elif kind == "idm":
        limit = env.road.network.get_lane(old.lane_index).speed_limit
        new = IDMVehicle(env.road, position, heading, speed, target_speed=float(limit or speed))
    elif kind == "lane-keeper":
        new = ControlledVehicle(env.road, position, heading, speed, target_speed=speed)
    else:
        raise HighwayEnvSetupError(f"unknown ego kind {kind!r}; one of {', '.join(EGO_KINDS)}")
    env.road.vehicles[env.road.vehicles.index(old)] = new
    env.controlled_vehicles = [new]
    env.action_type.controlled_vehicle = new
    return new


class Recorder:
    """Every vehicle's state at every simulation frame of one episode, in preallocated arrays (``capacity``
    frames); frame 0 is recorded at construction. ``tracks()`` views what was recorded (no copy)."""

    def __init__(self, env: AbstractEnv, capacity: int) -> None:
        self.vehicles = list(env.road.vehicles)
        v = len(self.vehicles)
        self.ego_vehicle = env.vehicle
        self.ego = self.vehicles.index(env.vehicle)
        self.ids = np.arange(1, v + 1, dtype=np.int64)
        self.length_m = np.array([x.LENGTH for x in self.vehicles], dtype=np.float64)
        self.width_m = np.array([x.WIDTH for x in self.vehicles], dtype=np.float64)
        self.t_s = np.zeros(capacity)
        self.xy_m = np.zeros((v, capacity, 2))
        self.vxy_mps = np.zeros((v, capacity, 2))
        self.heading_rad = np.zeros((v, capacity))
        self.crashed = np.zeros((v, capacity), dtype=bool)
        self.on_road = np.zeros(capacity, dtype=bool)
        self.n = 0
        self.record(env)

    def record(self, env: AbstractEnv) -> None:
        """Append the current frame (at ``env.time``); the vehicles must be those of the first frame."""
        vehicles = env.road.vehicles
        if len(vehicles) != len(self.vehicles):
            raise HighwayEnvSetupError(f"{type(env).__name__} added or removed vehicles during the episode "
                                       f"({len(self.vehicles)} -> {len(vehicles)}): letspi records a fixed set")
        if self.n >= len(self.t_s):
            raise ValueError(f"Recorder: more than its capacity of {len(self.t_s)} frames")
        k = self.n
        self.t_s[k] = env.time
        self.xy_m[:, k] = [x.position for x in self.vehicles]
        speed = np.array([x.speed for x in self.vehicles], dtype=np.float64)
        heading = np.array([x.heading for x in self.vehicles], dtype=np.float64)
        self.heading_rad[:, k] = heading
        self.vxy_mps[:, k, 0] = speed * np.cos(heading)
        self.vxy_mps[:, k, 1] = speed * np.sin(heading)
        self.crashed[:, k] = [x.crashed for x in self.vehicles]
        self.on_road[k] = self.ego_vehicle.on_road
        self.n += 1

    def tracks(self) -> EpisodeTracks:
        n = self.n
        return EpisodeTracks(self.t_s[:n], self.xy_m[:, :n], self.vxy_mps[:, :n], self.heading_rad[:, :n],
                             self.crashed[:, :n], self.ids, self.length_m, self.width_m, self.ego, self.on_road[:n])


@dataclass
class StepTiming:
    """Wall seconds of one policy period: highway-env's own simulation (``road.act`` and ``road.step`` without
    the ego's control), the ego's control, the recording."""

    highway_env_s: float = 0.0
    control_s: float = 0.0
    record_s: float = 0.0


def advance(env: AbstractEnv, recorder: Recorder, frames: int) -> StepTiming:
    """One policy period: ``frames`` simulation frames as ``AbstractEnv._simulate`` runs them, each recorded;
    ``env.time`` and ``env.steps`` advance as ``AbstractEnv.step`` advances them."""
    hz = env.config["simulation_frequency"]
    dt = 1.0 / hz
    ego = env.vehicle
    control0 = getattr(ego, "control_s", 0.0)
    timing = StepTiming()
    for _ in range(frames):
        t0 = time.perf_counter()
        env.road.act()
        env.road.step(dt)
        env.steps += 1
        env.time = env.steps / hz  # frames / rate: 450 frames at 15 Hz are 30.0 s exactly, not a sum of 1/15
        t1 = time.perf_counter()
        recorder.record(env)
        timing.highway_env_s += t1 - t0
        timing.record_s += time.perf_counter() - t1
    timing.control_s = getattr(ego, "control_s", 0.0) - control0
    timing.highway_env_s -= timing.control_s
    return timing


def ended(env: AbstractEnv) -> bool:
    """The episode is over: the ego crashed or left the road, or the environment terminates or truncates it."""
    ego = env.vehicle
    return bool(ego.crashed or not ego.on_road or env._is_terminated() or env._is_truncated())
