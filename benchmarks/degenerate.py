"""Random and degenerate straight-road scenes for robustness checks (``python -m benchmarks.speed robustness``).

``DEGENERATE_KINDS``: ``random`` (0-8 neighbours within ±80 m on 1-4 lanes, speeds 0-45 m/s, some appearing
late), ``no_neighbours``, ``overlap`` (8 boxes overlapping the ego at t = 0), ``zero_speed``, ``one_lane`` and
``nan_gaps`` (NaN runs in neighbour tracks, some on frames still marked valid: the one kind no recording makes).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Final

import numpy as np

from letspi.constants import MAX_NEIGHBOURS, N_TOTAL, T0_INDEX
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import VEHICLE_CLASS_CAR, VEHICLE_CLASS_TRUCK, ScenarioBatch, concat_batches

DEGENERATE_KINDS: Final = ("random", "no_neighbours", "overlap", "zero_speed", "one_lane", "nan_gaps")


def _random_vehicle(rng: np.random.Generator, n_lanes: int, ego_lane: int) -> VehicleSpec:
    truck = rng.random() < 0.2
    return VehicleSpec(
        x0_m=float(rng.uniform(-80.0, 80.0)),
        speed_mps=float(rng.uniform(0.1, 45.0)),  # > 0: braking stops at 0 instead of reversing
        lane_offset=int(rng.integers(-ego_lane, n_lanes - ego_lane)),
        accel_mps2=float(rng.uniform(-6.0, 3.0)),
        y_offset_m=float(rng.uniform(-0.8, 0.8)),
        length_m=float(rng.uniform(12.0, 18.0) if truck else rng.uniform(3.5, 5.5)),
        width_m=float(rng.uniform(2.3, 2.6) if truck else rng.uniform(1.6, 2.1)),
        vehicle_class=VEHICLE_CLASS_TRUCK if truck else VEHICLE_CLASS_CAR,
        visible_from_index=int(rng.integers(0, T0_INDEX + 1)) if rng.random() < 0.15 else 0,
    )


def _scene(kind: str, rng: np.random.Generator, scenario_id: str) -> ScenarioBatch:
    if kind == "random":
        n_lanes = int(rng.integers(1, 5))
        ego_lane = int(rng.integers(0, n_lanes))
        n_nbrs = int(rng.integers(0, MAX_NEIGHBOURS + 1))
        return straight_road_scenario(
            ego_speed_mps=float(rng.uniform(0.1, 45.0)), ego_accel_mps2=float(rng.uniform(-5.0, 2.0)),
            neighbours=[_random_vehicle(rng, n_lanes, ego_lane) for _ in range(n_nbrs)],
            n_lanes=n_lanes, ego_lane_index=ego_lane, scenario_id=scenario_id)
    if kind == "no_neighbours":
        n_lanes = int(rng.integers(1, 5))
        return straight_road_scenario(ego_speed_mps=float(rng.uniform(0.0, 45.0)), n_lanes=n_lanes,
                                      ego_lane_index=int(rng.integers(0, n_lanes)), scenario_id=scenario_id)
    if kind == "overlap":
        v = float(rng.uniform(0.0, 40.0))
        nbrs = [VehicleSpec(x0_m=float(rng.uniform(-3.0, 3.0)), speed_mps=float(max(0.0, v + rng.normal(0.0, 3.0))),
                            lane_offset=0, y_offset_m=float(rng.uniform(-1.0, 1.0)))
                for _ in range(MAX_NEIGHBOURS)]
        return straight_road_scenario(ego_speed_mps=v, neighbours=nbrs, scenario_id=scenario_id)
    if kind == "zero_speed":
        jam = rng.random() < 0.5
        nbrs = [VehicleSpec(x0_m=float(x), speed_mps=0.0 if jam else float(rng.uniform(0.0, 30.0)),
                            lane_offset=int(rng.integers(-1, 2)))
                for x in rng.choice([-30.0, -15.0, 8.0, 15.0, 30.0, 45.0], size=int(rng.integers(0, 6)), replace=False)]
        return straight_road_scenario(ego_speed_mps=0.0, neighbours=nbrs, scenario_id=scenario_id)
    if kind == "one_lane":
        nbrs = [VehicleSpec(x0_m=float(x), speed_mps=float(rng.uniform(0.0, 40.0)),
                            accel_mps2=float(rng.uniform(-6.0, 2.0)))
                for x in (float(rng.uniform(6.0, 60.0)), float(rng.uniform(-60.0, -6.0)))[: int(rng.integers(0, 3))]]
        return straight_road_scenario(ego_speed_mps=float(rng.uniform(0.0, 40.0)), neighbours=nbrs, n_lanes=1,
                                      ego_lane_index=0, scenario_id=scenario_id)
    if kind == "nan_gaps":
        base = _scene("random", rng, scenario_id)
        return _with_nan_gaps(base, rng)
    raise ValueError(f"unknown degenerate scene kind {kind!r}; known: {', '.join(DEGENERATE_KINDS)}")


def _with_nan_gaps(batch: ScenarioBatch, rng: np.random.Generator) -> ScenarioBatch:
    """NaN runs in the neighbours' tracks (history and future): invisible gaps, and in half of the
    scenes NaN values on frames still marked valid."""
    xy, vxy, valid = batch.nbr_xy_m.copy(), batch.nbr_vxy_mps.copy(), batch.nbr_valid.copy()
    inconsistent = rng.random() < 0.5
    for j in range(xy.shape[1]):
        if not valid[0, j].any():
            continue
        for _ in range(int(rng.integers(1, 4))):
            start = int(rng.integers(0, N_TOTAL))
            stop = min(N_TOTAL, start + int(rng.integers(1, 40)))
            xy[0, j, start:stop] = np.nan
            vxy[0, j, start:stop] = np.nan
            if not inconsistent:
                valid[0, j, start:stop] = False
    return replace(batch, nbr_xy_m=xy, nbr_vxy_mps=vxy, nbr_valid=valid)


def degenerate_scenarios(n: int, seed: int = 0, kinds: tuple[str, ...] = DEGENERATE_KINDS) -> ScenarioBatch:
    """``n`` scenes, kinds in turn (scene i has kind ``kinds[i % len(kinds)]``; its id starts with the kind)."""
    rng = np.random.default_rng(seed)
    scenes = [_scene(kinds[i % len(kinds)], rng, f"{kinds[i % len(kinds)]}-{i:06d}") for i in range(n)]
    return concat_batches(scenes)


def scene_kind(scenario_id: str) -> str:
    """The kind of a scene made by ``degenerate_scenarios`` (from its id)."""
    return scenario_id.rsplit("-", 1)[0]
