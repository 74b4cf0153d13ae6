"""The planner interface: scenarios in, planned ego futures out.

A planner sees what is known at t = 0: the harness passes non-oracle planners a history-only view
(``ScenarioBatch.history()``: every per-frame array ends at ``T0_INDEX``, the future is absent, not
blanked). The kinds that read the recorded future get the full batch: the ``human`` replay (the
reference row of every table) and the labelled oracle modes (oracle goals, ground-truth neighbour
replay), which are upper bounds, not planners. Which ones they are is the planner table's to say
(``letspi.assembly.planner_table``, ``BuiltPlanner.reads_future``), not the planner object's.
The harness (``letspi.evaluation.harness``) times ``plan`` calls; planners don't time themselves.

The social force planners (``sf``, ``sf-opt``, ``mlp``, ``gnp`` and the LLM planners) are also
``ProposingPlanner``s: a *propose* step that decides (parameters, goal adjustments; an LLM call per
scenario for the LLM planners) and a *simulate* step that runs the physics (rollout, safety shield)
batched over any set of proposals. The harness pools the proposals of LLM planners, made many at a
time, and simulates and scores them per part; the closed loop replans with them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from letspi.physics.goals import GoalPredictor, KinematicGoalPredictor
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.params import SocialForceParams
from letspi.physics.types import NeighbourPrediction
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

    ``batch_size`` says how many scenarios a caller should pass per call (the physics is vectorised
    over them). Planners whose cost is a model call per scenario say so with
    ``ProposingPlanner.proposes_per_scenario``: the harness then times each scenario's proposal on
    its own. Whether it reads the recorded future: see the module docstring.
    """

    name: str
    batch_size: int

    def plan(self, batch: ScenarioBatch) -> PlanBatch: ...


# ------------------------------------------------------------------------------------------------
# Propose, then simulate
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PlanningContext:
    """What a planner derives from the observed scene before it decides (batched, no model call).

    Attributes:
        goals_xy_m: (B, 2) the goal predictor's top goal [m, ego frame], before any adjustment.
        neighbours: the predicted neighbours (B, N, F, ...) the rollout and the shield react to.
    """

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
    """What a planner decided per scenario before any physics (the *propose* step), B scenarios.

    Attributes:
        params: (B,) social force parameters as proposed (``simulate`` clamps them).
        lon_factor, lane_factor: (B,) goal adjustment factors (paper §III-D; NaN = no adjustment).
        info: per-scenario extras stored with the plan (``PlanBatch.info``), leading axis B.
        extra: per-scenario inputs of the planner's own ``simulate`` (leading axis B; e.g. GNP's
            neighbour weights, the retrieved memories a shield may fall back to); not stored.
    """

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
    """A planner split into its decision and its physics.

    * ``context(batch)``: goals and predicted neighbours, batched (no model call);
    * ``propose(batch, context)``: the decision per scenario: social force parameters and goal
      adjustments. ``proposes_per_scenario`` True means it calls a model once per scenario (the LLM
      planners): the harness then runs it on batches of one, many in flight, and pools the results;
    * ``simulate(batch, context, proposals)``: rollout, safety shield, plan; batched over any number
      of proposals, and a scenario's plan does not depend on which others share its batch.

    ``plan(batch)`` is ``simulate(batch, c, propose(batch, c))`` with ``c = context(batch)``. In closed
    loop the physics may replan with proposals made earlier (``letspi.simulation``).
    """

    proposes_per_scenario: bool

    def context(self, batch: ScenarioBatch) -> PlanningContext: ...

    def propose(self, batch: ScenarioBatch, context: PlanningContext) -> Proposals: ...

    def simulate(self, batch: ScenarioBatch, context: PlanningContext, proposals: Proposals) -> PlanBatch: ...


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
    """The shared step of the social-force-family planners (``sf``, ``sf-opt``, ``mlp``, ``gnp``): the
    context is the goal predictor's top goal and the neighbours predicted by ``neighbour_mode``, and
    ``plan`` is propose-then-simulate (``plan_by_proposals``). A subclass adds its fields (``name``,
    ``batch_size``, its model or parameters) and writes ``propose`` and ``simulate``.
    """

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
