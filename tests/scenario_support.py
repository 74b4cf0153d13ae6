"""Scenario batches shared by the scenario-file tests (corruption, CLI errors)."""

from __future__ import annotations

import dataclasses
from dataclasses import fields

import numpy as np

from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import ScenarioBatch


def noisy_batch(n: int, seed: int = 0) -> ScenarioBatch:
    """``n`` scenarios with noisy trajectories (so the file does not compress to nothing)."""
    base = straight_road_scenario(neighbours=[VehicleSpec(20.0, 25.0), VehicleSpec(-15.0, 30.0, lane_offset=1)])
    rng = np.random.default_rng(seed)
    out = {}
    for f in fields(ScenarioBatch):
        arr = np.repeat(getattr(base, f.name), n, axis=0)
        if f.name in ("ego_xy_m", "nbr_xy_m", "ego_vxy_mps"):
            arr = (arr + rng.normal(0.0, 1.0, arr.shape)).astype(arr.dtype)
        out[f.name] = arr
    out["scenario_id"] = np.array([f"s{i}" for i in range(n)], dtype=object)
    return dataclasses.replace(base, **out)
