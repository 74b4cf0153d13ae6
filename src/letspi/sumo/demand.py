"""Traffic demand: per-vehicle types (car / van / truck) and seeded arrivals per lane and direction.

Every vehicle gets its own SUMO ``vType`` so that dimensions and driver parameters vary from
vehicle to vehicle like in real data; all randomness comes from one ``numpy`` generator seeded by
the caller, so a seed fully determines the demand (SUMO itself runs with sigma = 0).

Car following is IDM with sigma 0 (Krauss' random dawdling gives unrealistic jerk at 25 Hz);
lane changing is LC2013 (keep-right, no overtaking on the right, speed-gain overtaking of
trucks). HighD only knows "Car" and "Truck": vans are simulated with van dimensions and dynamics
but labelled "Car", exactly as HighD labels them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal
from xml.sax.saxutils import quoteattr

import numpy as np

from letspi.sumo.network import EASTBOUND_EDGE, WESTBOUND_EDGE

Kind = Literal["car", "van", "truck"]

DEFAULT_FLOW_PER_LANE_VEH_PER_H = 600.0
"""Default demand per lane and direction [veh/h]: 1,800 veh/h per direction on 3 lanes.

Middle of the HighD range (about 1,000-2,500 veh/h per direction): dense enough for
car-following interactions and truck overtaking, below capacity so no jams form."""


@dataclass(frozen=True)
class DemandConfig:
    """Demand parameters.

    Attributes:
        truck_share: fraction of trucks among all vehicles (HighD: roughly 15-25 %).
        van_share: fraction of vans (labelled "Car" in HighD files).
        min_headway_s: minimum time headway [s] between insertions on one lane; the rest of the
            headway is exponential (shifted-exponential arrivals, a standard free-flow model).
    """

    truck_share: float = 0.15
    van_share: float = 0.08
    min_headway_s: float = 1.2


@dataclass(frozen=True)
class VehicleSpec:
    """One vehicle to insert.

    Attributes:
        vid: SUMO vehicle id.
        kind: "car", "van" or "truck".
        edge: SUMO edge ("E" eastbound = HighD direction 2, "W" = direction 1).
        lane: SUMO lane index at insertion (0 = rightmost).
        depart_s: insertion time [s].
        length_m, width_m: dimensions [m].
        desired_speed_mps: desired speed [m/s] (= desiredMaxSpeed * speedFactor).
        accel_mps2: IDM maximum acceleration a [m/s²].
        decel_mps2: IDM comfortable deceleration b [m/s²].
        headway_s: IDM desired time headway T [s].
        min_gap_m: IDM jam distance s0 [m].
    """

    vid: str
    kind: Kind
    edge: str
    lane: int
    depart_s: float
    length_m: float
    width_m: float
    desired_speed_mps: float
    accel_mps2: float
    decel_mps2: float
    headway_s: float
    min_gap_m: float


def _lane_shares(n_lanes: int) -> np.ndarray:
    """Share of the flow entering on each SUMO lane (index 0 = rightmost)."""
    if n_lanes == 2:
        return np.array([0.55, 0.45])
    if n_lanes == 3:
        return np.array([0.36, 0.38, 0.26])
    raise ValueError(f"lanes_per_direction must be 2 or 3, got {n_lanes}")


def _truck_lane_shares(n_lanes: int) -> np.ndarray:
    """Where trucks enter: mostly the right lane, some in the next one (overtaking trucks)."""
    shares = np.zeros(n_lanes)
    shares[0], shares[1] = 0.88, 0.12
    return shares


def _clipped_normal(rng: np.random.Generator, mean: float, sd: float, lo: float, hi: float) -> float:
    return float(np.clip(rng.normal(mean, sd), lo, hi))


def _sample_vehicle(rng: np.random.Generator, kind: Kind) -> dict[str, float]:
    """Dimensions [m], desired speed [m/s] and IDM parameters for one vehicle of a class."""
    if kind == "truck":
        # Mix of articulated trucks (about 16.5 m) and rigid trucks / buses (about 10-12 m).
        if rng.random() < 0.7:
            length = _clipped_normal(rng, 16.3, 0.6, 14.5, 18.75)
        else:
            length = _clipped_normal(rng, 10.5, 1.3, 8.0, 13.0)
        return {
            "length_m": length,
            "width_m": _clipped_normal(rng, 2.50, 0.04, 2.40, 2.60),
            # German trucks: 80 km/h limit, actually driven at about 85-90 km/h.
            "desired_speed_mps": _clipped_normal(rng, 24.0, 0.9, 22.0, 26.5),
            "accel_mps2": _clipped_normal(rng, 0.6, 0.1, 0.4, 0.9),
            "decel_mps2": 2.0,
            "headway_s": _clipped_normal(rng, 1.7, 0.2, 1.3, 2.3),
            "min_gap_m": 2.5,
        }
    if kind == "van":
        return {
            "length_m": _clipped_normal(rng, 5.6, 0.5, 4.8, 7.0),
            "width_m": _clipped_normal(rng, 2.0, 0.05, 1.9, 2.15),
            "desired_speed_mps": _clipped_normal(rng, 31.0, 2.5, 25.0, 38.0),
            "accel_mps2": _clipped_normal(rng, 1.1, 0.15, 0.8, 1.5),
            "decel_mps2": 2.5,
            "headway_s": _clipped_normal(rng, 1.4, 0.2, 1.0, 2.0),
            "min_gap_m": 2.0,
        }
    return {
        "length_m": _clipped_normal(rng, 4.55, 0.35, 3.6, 5.3),
        "width_m": _clipped_normal(rng, 1.82, 0.07, 1.6, 2.0),
        # Unrestricted autobahn: cars mostly 110-150 km/h.
        "desired_speed_mps": _clipped_normal(rng, 35.0, 4.0, 26.0, 47.0),
        "accel_mps2": _clipped_normal(rng, 1.4, 0.2, 1.0, 2.0),
        "decel_mps2": 2.5,
        "headway_s": _clipped_normal(rng, 1.3, 0.25, 0.8, 2.0),
        "min_gap_m": 2.0,
    }


def sample_demand(
    rng: np.random.Generator,
    *,
    lanes_per_direction: int,
    flow_veh_per_h: float,
    end_s: float,
    config: DemandConfig | None = None,
) -> list[VehicleSpec]:
    """Draw all vehicles for both directions, sorted by departure time.

    Args:
        rng: seeded generator (the only source of randomness).
        lanes_per_direction: 2 or 3.
        flow_veh_per_h: demand per direction [veh/h].
        end_s: no insertions at or after this time [s].
        config: class shares and headway model.

    Returns:
        Vehicle specs ordered by (depart_s, vid).
    """
    cfg = config or DemandConfig()
    lane_shares = _lane_shares(lanes_per_direction)
    truck_lanes = _truck_lane_shares(lanes_per_direction)
    specs: list[VehicleSpec] = []
    counter = 0
    for edge in (EASTBOUND_EDGE, WESTBOUND_EDGE):
        for lane in range(lanes_per_direction):
            rate_per_s = flow_veh_per_h * lane_shares[lane] / 3600.0
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
                params = _sample_vehicle(rng, kind)
                specs.append(VehicleSpec(vid=f"{edge}{counter}", kind=kind, edge=edge, lane=lane,
                                         depart_s=round(t, 2), **params))
                counter += 1
                t += cfg.min_headway_s + float(rng.exponential(mean_extra))
    specs.sort(key=lambda s: (s.depart_s, s.vid))
    return specs


# SUMO's maxSpeed is the technical top speed; the desired speed is desiredMaxSpeed*speedFactor.
_MAX_SPEED_MPS: dict[Kind, float] = {"car": 60.0, "van": 45.0, "truck": 28.0}
# LC2013: trucks are less eager to overtake; everyone keeps right.
_LC_PARAMS: dict[Kind, str] = {
    "car": 'lcKeepRight="1.0" lcSpeedGain="1.0" lcCooperative="1.0" lcAssertive="1.0"',
    "van": 'lcKeepRight="1.0" lcSpeedGain="0.9" lcCooperative="1.0" lcAssertive="1.0"',
    "truck": 'lcKeepRight="1.5" lcSpeedGain="0.4" lcCooperative="1.0" lcAssertive="1.0"',
}
_VCLASS: dict[Kind, str] = {"car": "passenger", "van": "delivery", "truck": "truck"}


def write_routes(path: Path, specs: list[VehicleSpec]) -> None:
    """Write the SUMO route file: one vType per vehicle, one route per direction."""
    lines = ["<routes>",
             f'  <route id="r{EASTBOUND_EDGE}" edges="{EASTBOUND_EDGE}"/>',
             f'  <route id="r{WESTBOUND_EDGE}" edges="{WESTBOUND_EDGE}"/>']
    for s in specs:
        desired = min(s.desired_speed_mps, _MAX_SPEED_MPS[s.kind])
        lines.append(
            f'  <vType id={quoteattr("t" + s.vid)} vClass="{_VCLASS[s.kind]}" carFollowModel="IDM" '
            f'sigma="0" delta="4" length="{s.length_m:.3f}" width="{s.width_m:.3f}" '
            f'maxSpeed="{_MAX_SPEED_MPS[s.kind]:.2f}" desiredMaxSpeed="{desired:.4f}" speedFactor="1" '
            f'speedDev="0" accel="{s.accel_mps2:.3f}" decel="{s.decel_mps2:.3f}" emergencyDecel="9" '
            f'tau="{s.headway_s:.3f}" minGap="{s.min_gap_m:.2f}" {_LC_PARAMS[s.kind]}/>'
        )
        lines.append(
            f'  <vehicle id={quoteattr(s.vid)} type={quoteattr("t" + s.vid)} route="r{s.edge}" '
            f'depart="{s.depart_s:.2f}" departLane="{s.lane}" departPos="base" departSpeed="max"/>'
        )
    lines.append("</routes>")
    path.write_text("\n".join(lines) + "\n")
