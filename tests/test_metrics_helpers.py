"""Shared builders for the metrics tests (hand-built straight-road scenarios and plans; no tests here)."""

from __future__ import annotations

import numpy as np

from letspi.constants import DT_S, N_FUTURE
from letspi.metrics.inputs import MetricInputs
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import ScenarioBatch

T_FUT = (np.arange(N_FUTURE) + 1) * DT_S  # time of each future step after t = 0


def constant_speed_plan(
    speed_mps: float, x0_m: float = 0.0, y_m: np.ndarray | float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """(1, F, 2) positions and velocities of an ego at constant speed along x, lateral y (per step)."""
    x = x0_m + speed_mps * T_FUT
    y = np.broadcast_to(np.asarray(y_m, dtype=np.float64), x.shape)
    xy = np.stack([x, y], -1)[None]
    v = np.stack([np.full_like(x, speed_mps), np.zeros_like(x)], -1)[None]
    return xy, v


def make(neighbours: list[VehicleSpec], **kw: object) -> ScenarioBatch:
    return straight_road_scenario(neighbours=neighbours, **kw)  # type: ignore[arg-type]


def inputs(batch: ScenarioBatch, xy: np.ndarray, v: np.ndarray) -> MetricInputs:
    return MetricInputs.from_batch(batch, xy, v)
