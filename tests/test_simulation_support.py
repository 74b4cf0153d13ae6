"""Shared pieces of the closed-loop tests: generated traffic and small planners (no tests here).

The planners are module-level classes so worker processes (spawned) and Ray actors can unpickle them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from letspi.assembly.planners import BuiltPlanner
from letspi.constants import DT_S, N_FUTURE, T0_INDEX
from letspi.highd.io import read_recordings
from letspi.planners.base import PlanBatch, Planner
from letspi.planners.cv import CvConfig
from letspi.planners.human import HumanConfig
from letspi.scenario.extract import extract_scenarios
from letspi.scenario.types import ScenarioBatch
from letspi.trafficgen.generate import generate_highd


def as_built(planner: Planner | object) -> object:
    """A test planner as the closed loop takes it: a ``BuiltPlanner`` of kind ``human`` (it gets the recorded
    future) when it says ``reads_future``, else of kind ``cv`` (history only). Specs pass through."""
    if not isinstance(planner, Planner) or isinstance(planner, BuiltPlanner):
        return planner
    config = HumanConfig() if getattr(planner, "reads_future", False) else CvConfig()
    return BuiltPlanner(planner.name, config, planner)


def generated_batch(directory: Path, n: int = 48, seed: int = 3, minutes: float = 1.0,
                    criticality: str = "calm") -> ScenarioBatch:
    """``n`` scenarios (both driving directions) of SUMO-generated HighD-format traffic (the engine tests
    were written on the calm preset, the generator's default before critical traffic)."""
    generate_highd(directory, minutes=minutes, seed=seed, criticality=criticality)
    batch = extract_scenarios(read_recordings(directory))
    step = max(1, len(batch) // n)
    return batch.take(np.arange(0, len(batch), step)[:n])


@dataclass
class BrakePlanner:
    """Brakes at ``decel_mps2`` along its current heading from whatever state it is given."""

    decel_mps2: float = 8.0
    name: str = "brake"
    batch_size: int = 4096
    reads_future: bool = False

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        v0 = batch.ego_vxy_mps[:, T0_INDEX].astype(np.float64)
        speed = np.hypot(v0[:, 0], v0[:, 1])
        t = np.arange(1, N_FUTURE + 1) * DT_S
        s = np.maximum(speed[:, None] - self.decel_mps2 * t[None], 0.0)
        heading = v0 / np.maximum(speed, 1e-9)[:, None]
        xy = (np.cumsum(s, axis=1) * DT_S)[..., None] * heading[:, None, :]
        return PlanBatch(xy, s[..., None] * heading[:, None, :], xy[:, -1].copy())


@dataclass
class SwervePlanner:
    """Keeps its speed and drifts sideways at ``lateral_mps`` (left or right by scenario id): side swipes."""

    lateral_mps: float = 1.5
    name: str = "swerve"
    batch_size: int = 4096
    reads_future: bool = False

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        v0 = batch.ego_vxy_mps[:, T0_INDEX].astype(np.float64)
        t = np.arange(1, N_FUTURE + 1) * DT_S
        side = np.array([1.0 if sum(map(ord, str(s))) % 2 else -1.0 for s in batch.scenario_id])
        vy = np.minimum(self.lateral_mps * t / 0.5, self.lateral_mps)[None] * side[:, None]
        y = np.cumsum(vy, axis=1) * DT_S
        x = v0[:, 0:1] * t[None]
        vxy = np.stack([np.broadcast_to(v0[:, 0:1], x.shape), vy], -1)
        return PlanBatch(np.stack([x, y], -1), vxy, np.stack([x[:, -1], y[:, -1]], -1))


@dataclass
class RecordingPlanner:
    """Constant velocity; keeps every batch it was given (for checking what planners see)."""

    reads_future: bool = False
    name: str = "recorder"
    batch_size: int = 4096

    def __post_init__(self) -> None:
        self.seen: list[ScenarioBatch] = []

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        self.seen.append(batch)
        v0 = batch.ego_vxy_mps[:, T0_INDEX].astype(np.float64)
        t = np.arange(1, N_FUTURE + 1) * DT_S
        xy = v0[:, None, :] * t[None, :, None]
        return PlanBatch(xy, np.repeat(v0[:, None, :], N_FUTURE, axis=1), xy[:, -1].copy())


@dataclass
class FailingPlanner:
    """Raises on its first call (a planner bug inside a worker)."""

    name: str = "failing"
    batch_size: int = 4096
    reads_future: bool = False

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        raise RuntimeError("planner bug for the test")


@dataclass
class WildPlanner:
    """Constant velocity, except: NaN plans for the first scenario, plans 1 km to the left for the second."""

    name: str = "wild"
    batch_size: int = 4096
    reads_future: bool = False

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        v0 = batch.ego_vxy_mps[:, T0_INDEX].astype(np.float64)
        t = np.arange(1, N_FUTURE + 1) * DT_S
        xy = v0[:, None, :] * t[None, :, None]
        xy[0] = np.nan
        if len(batch) > 1:
            xy[1, :, 1] = 1000.0
        return PlanBatch(xy, np.repeat(v0[:, None, :], N_FUTURE, axis=1), xy[:, -1].copy())
