"""Traffic demand: one SUMO ``vType`` per vehicle (car / van / truck; EIDM without driver error, LC2013) and seeded
arrivals per lane and direction; the caller's numpy generator is the only randomness (SUMO runs with sigma = 0)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal
from xml.sax.saxutils import quoteattr

import numpy as np

from letspi.trafficgen.config import DriverConfig
from letspi.trafficgen.network import Entry

Kind = Literal["car", "van", "truck"]

_STEP_S = 0.04  # simulation step: reaction times are multiples of it
DEFAULT_FLOW_PER_LANE_VEH_PER_H = 2200.0 / 3.0
"""Default demand per lane and direction [veh/h]: 2,200 veh/h per direction on 3 lanes.

Upper half of the HighD range (about 1,000-2,500 veh/h per direction): dense enough for
frequent car following at short headways, cut-ins and truck overtaking, below capacity so no
jams form."""


@dataclass(frozen=True)
class DemandConfig:
    """Demand: ``truck_share`` and ``van_share`` of all vehicles; ``min_headway_s`` [s] between insertions on one lane
    plus an exponential rest (shifted-exponential free-flow arrivals); ``drivers``: per-driver behaviour."""

    truck_share: float = 0.15
    van_share: float = 0.08
    min_headway_s: float = 1.2
    drivers: DriverConfig = field(default_factory=DriverConfig)


@dataclass(frozen=True)
class VehicleSpec:
    """One vehicle to insert (all units SI). SUMO ``vid``, ``kind``, ``route``; ``east`` (HighD direction 2); insertion
    ``lane`` (0 = rightmost) and ``depart_s``; ``desired_speed_mps`` = desiredMaxSpeed · speedFactor; (E)IDM a, b, T, s0
    as ``accel_mps2``, ``decel_mps2``, ``headway_s``, ``min_gap_m``; LC2013 ``lcSpeedGain``, ``lcKeepRight``,
    ``lcCooperative``, ``lcAssertive`` (required gaps are divided by it) and ``lcSpeedGainLookahead``
    (``lc_lookahead_s``, 0 = SUMO's default); EIDM ``treaction`` (``reaction_time_s``) and ``epsilonacc``."""

    vid: str
    kind: Kind
    route: str
    east: bool
    lane: int
    depart_s: float
    length_m: float
    width_m: float
    desired_speed_mps: float
    accel_mps2: float
    decel_mps2: float
    headway_s: float
    min_gap_m: float
    lc_speed_gain: float
    lc_keep_right: float
    lc_cooperative: float
    lc_assertive: float
    reaction_time_s: float = 0.5
    lc_lookahead_s: float = 0.0
    impatient: bool = False
    epsilon_acc_mps2: float = 1.0


_LANE_SHARES: dict[int, tuple[float, ...]] = {
    1: (1.0,), 2: (0.55, 0.45), 3: (0.36, 0.38, 0.26), 4: (0.26, 0.28, 0.27, 0.19),
}


def _lane_shares(n_lanes: int) -> np.ndarray:
    """Share of the flow entering on each SUMO lane (index 0 = rightmost)."""
    if n_lanes not in _LANE_SHARES:
        raise ValueError(f"insertion on {n_lanes} lanes is not supported (1-4)")
    return np.asarray(_LANE_SHARES[n_lanes])


def _truck_lane_shares(n_lanes: int) -> np.ndarray:
    """Where trucks enter: mostly the right lane, some in the next one (overtaking trucks)."""
    shares = np.zeros(n_lanes)
    if n_lanes == 1:
        shares[0] = 1.0
    else:
        shares[0], shares[1] = 0.88, 0.12
    return shares


def _clipped_normal(rng: np.random.Generator, mean: float, sd: float, lo: float, hi: float) -> float:
    return float(np.clip(rng.normal(mean, sd), lo, hi))


def _sample_vehicle(rng: np.random.Generator, kind: Kind, drivers: DriverConfig) -> dict[str, float | bool]:
    """Dimensions [m], desired speed [m/s], EIDM and LC2013 parameters of one vehicle of a class."""
    if kind == "truck":
        params = _truck_params(rng)
    elif kind == "van":
        params = _van_params(rng, drivers)
    else:
        params = _car_params(rng, drivers)
    _apply_reaction_time(rng, params, drivers)
    return params


def _truck_params(rng: np.random.Generator) -> dict[str, float | bool]:
    """A truck's dimensions, desired speed, EIDM and LC2013 parameters (before the reaction time)."""
    # Mix of articulated trucks (about 16.5 m) and rigid trucks / buses (about 10-12 m).
    if rng.random() < 0.7:
        length = _clipped_normal(rng, 16.3, 0.6, 14.5, 18.75)
    else:
        length = _clipped_normal(rng, 10.5, 1.3, 8.0, 13.0)
    return {
        "length_m": length,
        "width_m": _clipped_normal(rng, 2.50, 0.04, 2.40, 2.60),
        # German trucks: 80 km/h limit, actually driven at about 85-90 km/h.
        "desired_speed_mps": _clipped_normal(rng, 24.0, 1.0, 21.5, 26.5),
        "accel_mps2": _clipped_normal(rng, 0.6, 0.1, 0.4, 0.9),
        "decel_mps2": _clipped_normal(rng, 2.2, 0.3, 1.8, 3.0),
        "headway_s": _clipped_normal(rng, 1.55, 0.25, 1.2, 2.1),
        "min_gap_m": float(rng.uniform(2.0, 3.0)),
        "lc_speed_gain": float(rng.uniform(0.3, 1.0)),
        "lc_keep_right": float(rng.uniform(1.0, 2.0)),
        "lc_cooperative": float(rng.uniform(0.7, 1.0)),
        "lc_assertive": float(rng.uniform(1.0, 1.5)),
    }


def _van_params(rng: np.random.Generator, drivers: DriverConfig) -> dict[str, float | bool]:
    """A van's dimensions, desired speed, EIDM and LC2013 parameters (before the reaction time)."""
    return {
        "length_m": _clipped_normal(rng, 5.6, 0.5, 4.8, 7.0),
        "width_m": _clipped_normal(rng, 2.0, 0.05, 1.9, 2.15),
        "desired_speed_mps": _clipped_normal(rng, 32.0, 3.0, 25.0, 40.0),
        "accel_mps2": _clipped_normal(rng, 1.3, 0.25, 0.8, 2.0),
        "decel_mps2": _clipped_normal(rng, 2.8, 0.4, 2.0, 3.8),
        "headway_s": _clipped_normal(rng, 1.1, 0.25, max(drivers.min_headway_s, 0.65), 1.6),
        "min_gap_m": float(rng.uniform(1.5, 2.5)),
        "lc_speed_gain": float(rng.uniform(1.0, 3.0)),
        "lc_keep_right": float(rng.uniform(0.5, 1.5)),
        "lc_cooperative": float(rng.uniform(0.3, 1.0)),
        "lc_assertive": float(rng.uniform(1.0, 2.0)),
    }


def _car_params(rng: np.random.Generator, drivers: DriverConfig) -> dict[str, float | bool]:
    """A car's dimensions, desired speed, EIDM and LC2013 parameters (before the reaction time);
    a share ``drivers.impatient_share`` of drivers is impatient (faster, tailgating, assertive)."""
    lo_hw = drivers.min_headway_s
    mean_hw, sd_hw = drivers.car_headway_s
    params: dict[str, float | bool] = {
        "length_m": _clipped_normal(rng, 4.55, 0.35, 3.6, 5.3),
        "width_m": _clipped_normal(rng, 1.82, 0.07, 1.6, 2.0),
        # Unrestricted autobahn: cars mostly 110-160 km/h, some much faster.
        "desired_speed_mps": _clipped_normal(rng, 36.5, 4.5, 26.0, 50.0),
        "accel_mps2": _clipped_normal(rng, 1.8, 0.4, 1.0, 3.0),
        "decel_mps2": _clipped_normal(rng, 3.0, 0.5, 2.0, 4.5),
        "headway_s": _clipped_normal(rng, mean_hw, sd_hw, lo_hw, max(lo_hw, 1.6)),
        "min_gap_m": float(rng.uniform(1.5, 2.5)),
        "lc_speed_gain": float(rng.uniform(1.0, 4.0)),
        "lc_keep_right": float(rng.uniform(0.5, 1.5)),
        "lc_cooperative": float(rng.uniform(0.2, 1.0)),
        "lc_assertive": (float(rng.uniform(*drivers.assertive_range))
                         if rng.random() < drivers.assertive_share else 1.0),
    }
    if drivers.impatient_share > 0 and rng.random() < drivers.impatient_share:
        params.update(
            impatient=True,
            desired_speed_mps=min(50.0, float(params["desired_speed_mps"]) * 1.1),
            headway_s=lo_hw,
            lc_speed_gain=float(params["lc_speed_gain"]) * 2.0,
            lc_keep_right=0.3,
            lc_cooperative=0.1,
            lc_assertive=max(float(params["lc_assertive"]), drivers.assertive_range[0]),
            lc_lookahead_s=2.0,
        )
    return params


def _apply_reaction_time(rng: np.random.Generator, params: dict[str, float | bool], drivers: DriverConfig) -> None:
    """Draw the reaction time (on the simulation grid) and apply the preset's scales, in place."""
    # Reaction time on the simulation grid; the desired headway never undercuts it (SUMO:
    # tau below the reaction time causes very hard braking or collisions).
    lo, hi = drivers.reaction_time_s
    # No draw for a fixed reaction time: the calm preset then draws exactly the v0.1 demand.
    drawn = float(rng.uniform(lo, hi)) if hi > lo else lo
    reaction = max(_STEP_S, round(drawn / _STEP_S + 1e-9) * _STEP_S)  # 0.5 / 0.04 is 12.4999...
    params["reaction_time_s"] = reaction
    params["epsilon_acc_mps2"] = drivers.epsilon_acc_mps2
    params["lc_speed_gain"] = float(params["lc_speed_gain"]) * drivers.lc_speed_gain_scale
    params["lc_keep_right"] = float(params["lc_keep_right"]) * drivers.lc_keep_right_scale
    params["headway_s"] = max(float(params["headway_s"]), reaction)


def sample_demand(
    rng: np.random.Generator,
    *,
    entries: list[Entry],
    flow_veh_per_h: float,
    end_s: float,
    config: DemandConfig | None = None,
) -> list[VehicleSpec]:
    """All vehicles of all ``entries`` departing before ``end_s`` [s], ordered by (depart_s, vid);
    ``flow_veh_per_h`` is per direction."""
    cfg = config or DemandConfig()
    specs: list[VehicleSpec] = []
    counter = 0
    for entry in entries:
        lane_shares = _lane_shares(entry.n_lanes)
        truck_lanes = _truck_lane_shares(entry.n_lanes)
        for lane in range(entry.n_lanes):
            rate_per_s = flow_veh_per_h * entry.flow_share * lane_shares[lane] / 3600.0
            if rate_per_s <= 0.0:
                continue
            # Bayes: P(truck | lane) = P(lane | truck) P(truck) / P(lane).
            p_truck = min(0.95, truck_lanes[lane] * cfg.truck_share / lane_shares[lane])
            p_van = (1.0 - p_truck) * cfg.van_share / max(1e-9, 1.0 - cfg.truck_share)
            mean_extra = max(0.05, 1.0 / rate_per_s - cfg.min_headway_s)
            t = float(rng.uniform(0.0, 1.0 / rate_per_s))
            while t < end_s:
                u = rng.random()
                kind: Kind = "truck" if u < p_truck else ("van" if u < p_truck + p_van else "car")
                params = _sample_vehicle(rng, kind, cfg.drivers)
                prefix = "E" if entry.east else "W"
                specs.append(VehicleSpec(vid=f"{prefix}{counter}", kind=kind, route=entry.route, east=entry.east,
                                         lane=lane, depart_s=round(t, 2), **params))  # type: ignore[arg-type]
                counter += 1
                t += cfg.min_headway_s + float(rng.exponential(mean_extra))
    specs.sort(key=lambda s: (s.depart_s, s.vid))
    return specs


# SUMO's maxSpeed is the technical top speed; the desired speed is desiredMaxSpeed*speedFactor.
_MAX_SPEED_MPS: dict[Kind, float] = {"car": 60.0, "van": 45.0, "truck": 28.0}
_VCLASS: dict[Kind, str] = {"car": "passenger", "van": "delivery", "truck": "truck"}


def write_routes(path: Path, specs: list[VehicleSpec], routes: dict[str, list[str]],
                 lc_strategic: float | None = None) -> None:
    """Write the SUMO route file: one vType per vehicle and the routes (id -> edges); ``lc_strategic``: every
    driver's, if given."""
    strategic = f'lcStrategic="{lc_strategic:g}" ' if lc_strategic is not None else ""
    lines = ["<routes>"]
    lines += [f'  <route id={quoteattr(rid)} edges={quoteattr(" ".join(edges))}/>' for rid, edges in routes.items()]
    for s in specs:
        desired = min(s.desired_speed_mps, _MAX_SPEED_MPS[s.kind])
        lookahead = f'lcSpeedGainLookahead="{s.lc_lookahead_s:.2f}" ' if s.lc_lookahead_s > 0 else ""
        lines.append(
            f'  <vType id={quoteattr("t" + s.vid)} vClass="{_VCLASS[s.kind]}" carFollowModel="EIDM" '
            f'sigma="0" sigmaleader="0" sigmagap="0" sigmaerror="0" delta="4" '
            f'treaction="{s.reaction_time_s:.2f}" epsilonacc="{s.epsilon_acc_mps2:g}" '
            f'length="{s.length_m:.3f}" width="{s.width_m:.3f}" '
            f'maxSpeed="{_MAX_SPEED_MPS[s.kind]:.2f}" desiredMaxSpeed="{desired:.4f}" speedFactor="1" '
            f'speedDev="0" accel="{s.accel_mps2:.3f}" decel="{s.decel_mps2:.3f}" emergencyDecel="9" '
            f'tau="{s.headway_s:.3f}" minGap="{s.min_gap_m:.3f}" lcSpeedGain="{s.lc_speed_gain:.3f}" '
            f'lcKeepRight="{s.lc_keep_right:.3f}" lcCooperative="{s.lc_cooperative:.3f}" '
            f'lcAssertive="{s.lc_assertive:.3f}" {lookahead}{strategic}/>'
        )
        lines.append(
            f'  <vehicle id={quoteattr(s.vid)} type={quoteattr("t" + s.vid)} route={quoteattr(s.route)} '
            f'depart="{s.depart_s:.2f}" departLane="{s.lane}" departPos="base" departSpeed="max"/>'
        )
    lines.append("</routes>")
    path.write_text("\n".join(lines) + "\n")
