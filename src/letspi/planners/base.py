"""The planner interface: scenarios in, planned ego futures out.

A planner sees what is known at t = 0: the harness passes non-oracle planners a history-only view
(``ScenarioBatch.history()``: every per-frame array ends at ``T0_INDEX``, the future is absent, not
blanked). Planners that read the recorded future declare ``reads_future = True`` and get the full
batch: the ``human`` replay (the reference row of every table) and the labelled oracle modes (oracle
goals, ground-truth neighbour replay), which are upper bounds, not planners.
The harness (``letspi.evaluation.harness``) times ``plan`` calls; planners don't time themselves.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from letspi.scenario.types import ScenarioBatch


@dataclass(frozen=True)
class PlanBatch:
    """Planned ego futures for B scenarios (ego frame, F = 125 steps after t = 0).

    Attributes:
        xy_m: (B, F, 2) ego box-centre positions at t = 1..F frames.
        vxy_mps: (B, F, 2) ego velocities.
        goals_xy_m: (B, 2) the (possibly adjusted) goal the plan aimed at, NaN if none.
        info: per-scenario extras, each an array with leading axis B (parameters, flags, ...);
            stored beside the metrics in the per-scenario results.
    """

    xy_m: np.ndarray
    vxy_mps: np.ndarray
    goals_xy_m: np.ndarray
    info: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        b = self.xy_m.shape[0]
        if self.xy_m.ndim != 3 or self.xy_m.shape[2] != 2 or self.vxy_mps.shape != self.xy_m.shape:
            raise ValueError(f"PlanBatch: xy_m/vxy_mps must both be (B, F, 2), got {self.xy_m.shape}, "
                             f"{self.vxy_mps.shape}")
        if self.goals_xy_m.shape != (b, 2):
            raise ValueError(f"PlanBatch: goals_xy_m must be ({b}, 2), got {self.goals_xy_m.shape}")
        for k, v in self.info.items():
            if len(v) != b:
                raise ValueError(f"PlanBatch.info[{k!r}] has {len(v)} rows, expected {b}")


@runtime_checkable
class Planner(Protocol):
    """Anything with a ``name`` and a batched ``plan``.

    ``batch_size`` says how many scenarios the harness should pass per call: large for vectorised
    physics planners, 1 for planners whose cost is per scenario (LLMs), so per-scenario
    inference time is measured honestly. ``reads_future``: see the module docstring.
    """

    name: str
    batch_size: int
    reads_future: bool

    def plan(self, batch: ScenarioBatch) -> PlanBatch: ...
