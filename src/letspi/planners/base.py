"""The planner interface: scenarios in, planned ego futures out.

A planner gets a history-only view (``ScenarioBatch.history()``) unless its planner-table entry reads the future
(``BuiltPlanner.reads_future``). The social force family are also ``ProposingPlanner``s: a *propose* step that
decides and a batched *simulate* step that runs the physics, so the harness can pool proposals.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from letspi.physics.goals import GoalPredictor, KinematicGoalPredictor
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.params import SocialForceParams
from letspi.physics.types import NeighbourPrediction
from letspi.scenario.types import ScenarioBatch


@dataclass(frozen=True)
class PlanBatch:
    """Planned ego futures for B scenarios (ego frame, F = 125 steps after t = 0): ``xy_m`` (B, F, 2) box-centre
    positions [m] and ``vxy_mps`` (B, F, 2) at frames 1..F; ``goals_xy_m`` (B, 2) the goal aimed at (NaN if
    none); ``info``: per-scenario extras (leading axis B), stored beside the metrics."""

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
    """Anything with a ``name``, a batched ``plan`` and the ``batch_size`` a caller should pass per call."""

    name: str
    batch_size: int

    def plan(self, batch: ScenarioBatch) -> PlanBatch: ...


# Propose, then simulate -------------------------------------------------------------------------


@dataclass(frozen=True)
class PlanningContext:
    """What a planner derives before it decides (batched, no model call): ``goals_xy_m`` (B, 2) the top goal
    before adjustment [m, ego frame]; ``neighbours`` (B, N, F, ...) the prediction the rollout reacts to."""

    goals_xy_m: np.ndarray
    neighbours: NeighbourPrediction

    def __len__(self) -> int:
        return int(self.goals_xy_m.shape[0])

    def take(self, indices: np.ndarray | list[int] | slice) -> PlanningContext:
        return PlanningContext(np.asarray(self.goals_xy_m)[indices], self.neighbours.take(indices))

    @classmethod
    def concat(cls, parts: Sequence[PlanningContext]) -> PlanningContext:
        return cls(np.concatenate([p.goals_xy_m for p in parts]),
                   NeighbourPrediction.concat([p.neighbours for p in parts]))


@dataclass(frozen=True)
class Proposals:
    """The *propose* step's decisions, B scenarios: ``params`` (B,) as proposed (``simulate`` clamps them),
    goal adjustment factors ``lon_factor``, ``lane_factor`` (B,) (paper §III-D; NaN = none), ``info`` (stored
    with the plan) and ``extra`` (inputs of the planner's own ``simulate``, not stored), leading axis B."""

    params: SocialForceParams
    lon_factor: np.ndarray
    lane_factor: np.ndarray
    info: dict[str, np.ndarray] = field(default_factory=dict)
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        b = len(self.lon_factor)
        if len(self.params) != b or len(self.lane_factor) != b:
            raise ValueError(f"Proposals: {len(self.params)} parameter sets, {b} lon and {len(self.lane_factor)} "
                             "lane factors")
        for name, table in (("info", self.info), ("extra", self.extra)):
            for k, v in table.items():
                if len(v) != b:
                    raise ValueError(f"Proposals.{name}[{k!r}] has {len(v)} rows, expected {b}")

    def __len__(self) -> int:
        return len(self.lon_factor)

    def take(self, indices: np.ndarray | list[int] | slice) -> Proposals:
        idx = np.arange(len(self))[indices]
        return Proposals(
            params=SocialForceParams.from_matrix(self.params.as_matrix()[idx]),
            lon_factor=np.asarray(self.lon_factor, dtype=np.float64)[idx],
            lane_factor=np.asarray(self.lane_factor, dtype=np.float64)[idx],
            info={k: np.asarray(v)[idx] for k, v in self.info.items()},
            extra={k: np.asarray(v)[idx] for k, v in self.extra.items()},
        )

    @classmethod
    def concat(cls, parts: Sequence[Proposals]) -> Proposals:
        """The proposals of several batches, in order (the keys of the first one's ``info``/``extra``)."""
        if not parts:
            raise ValueError("Proposals.concat needs at least one batch")
        return cls(
            params=SocialForceParams.from_matrix(np.concatenate([p.params.as_matrix() for p in parts])),
            lon_factor=np.concatenate([np.asarray(p.lon_factor, dtype=np.float64) for p in parts]),
            lane_factor=np.concatenate([np.asarray(p.lane_factor, dtype=np.float64) for p in parts]),
            info={k: np.concatenate([np.asarray(p.info[k]) for p in parts]) for k in parts[0].info},
            extra={k: np.concatenate([np.asarray(p.extra[k]) for p in parts]) for k in parts[0].extra},
        )


@runtime_checkable
class ProposingPlanner(Planner, Protocol):
    """``plan(batch)`` is ``simulate(batch, c, propose(batch, c))`` with ``c = context(batch)``.
    ``proposes_per_scenario``: ``propose`` calls a model once per scenario (the harness passes batches of one).
    ``simulate`` is batched; a scenario's plan does not depend on which others share its batch."""

    proposes_per_scenario: bool

    def context(self, batch: ScenarioBatch) -> PlanningContext: ...

    def propose(self, batch: ScenarioBatch, context: PlanningContext) -> Proposals: ...

    def simulate(self, batch: ScenarioBatch, context: PlanningContext, proposals: Proposals) -> PlanBatch: ...


@runtime_checkable
class ModelPlanner(ProposingPlanner, Protocol):
    """A proposing planner that asks a model: ``advisor`` is the client it asks (its backend names the default
    number of calls in flight); ``concurrent_safe``: its ``propose`` may run in several threads at once."""

    concurrent_safe: bool

    @property
    def advisor(self) -> Any: ...


def plan_by_proposals(planner: ProposingPlanner, batch: ScenarioBatch) -> PlanBatch:
    """``planner.plan`` for a ``ProposingPlanner``: context, propose, simulate."""
    context = planner.context(batch)
    return planner.simulate(batch, context, planner.propose(batch, context))


def predicted_context(batch: ScenarioBatch, goal_predictor: GoalPredictor,
                      neighbour_mode: NeighbourPredictionMode) -> PlanningContext:
    """The top predicted goal and the predicted neighbours of every scenario of ``batch``."""
    return PlanningContext(goal_predictor.predict_goals(batch).top, predict_neighbours(batch, neighbour_mode))


@dataclass(kw_only=True)
class PredictingPlanner:
    """Base of the social-force-family planners: the context is the top predicted goal and ``neighbour_mode``'s
    prediction; a subclass adds ``name``, ``batch_size`` and its model, and writes ``propose`` and ``simulate``."""

    goal_predictor: GoalPredictor = field(default_factory=KinematicGoalPredictor)
    neighbour_mode: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    proposes_per_scenario: bool = False

    def context(self, batch: ScenarioBatch) -> PlanningContext:
        return predicted_context(batch, self.goal_predictor, self.neighbour_mode)

    def propose(self, batch: ScenarioBatch, context: PlanningContext) -> Proposals:
        raise NotImplementedError

    def simulate(self, batch: ScenarioBatch, context: PlanningContext, proposals: Proposals) -> PlanBatch:
        raise NotImplementedError

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        return plan_by_proposals(self, batch)  # type: ignore[arg-type]
