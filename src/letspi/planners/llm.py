"""LLM planners: ``llm`` (single shot), ``letspi-memory`` (memory-collection phase with reflection),
``letspi-fast`` (fast-inference phase with retrieved memories) and ``letspi-fs`` (the FS ablation:
the fast prompt with three static examples instead of retrieval).

They plan one scenario per call (``batch_size = 1``) so the harness times each LLM call honestly,
and ``plan`` is thread-safe (``concurrent_safe``): the harness keeps ``--concurrency`` scenarios in
flight (``letspi.method.runner``), all asking the planner's one ``advisor``. ``last_*`` attributes
describe the most recent call to finish (for ``letspi plan``, one scenario).
Per-scenario extras (``PlanBatch.info``) record the LLM side: tokens, fallbacks, clamps, reflection
iterations, whether the final plan was validated, and the timing honesty columns:

* ``llm_calls`` / ``llm_cached_calls``: model calls made for the scenario, and how many the response
  cache served; ``llm_cached`` is True when all of them were (the row's time is then a cache lookup);
* ``llm_latency_s``: wall time of the calls that really ran the model now;
* ``llm_original_latency_s``: what every call cost when it was first made (cache hits: the latency
  recorded with the cached reply), so a fully cached rerun still reports the model's cost.

Safety shield (beyond the paper; on by default, ``--no-shield`` is the paper-faithful ablation):
before a plan is returned, the reflection checks run once more against the *predicted* neighbours
(the planner's own prediction from history; no LLM call, milliseconds). If the plan fails, the
alternatives (the retrieved memories' parameters for ``letspi-fast``, the fitted ``sf`` parameters,
then ``sf-opt``'s candidate grid around them, cheapest first) are simulated and checked in one batch,
and the safest one is returned instead: the first safe alternative in that order, else the least
unsafe plan of all (possibly the original). Info columns: ``shielded`` (the plan was replaced),
``shield_checked`` (the shield ran), ``shield_safe`` (the returned plan passes the checks),
``shield_source`` (0 = the LLM's plan, 1..k = retrieved memory k, -1 = the fitted ``sf``
parameters, -2 = a grid candidate).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
from pydantic import Field

from letspi.llm.client import ParamAdvisor
from letspi.method.matching import TOP_K
from letspi.method.memory import MemoryBank
from letspi.method.phases import FastPhase, MemoryPhase
from letspi.method.reflection import IterationRecord, Proposal, SafetyReport, safety_report, simulate_proposal
from letspi.method.thresholds import ReflectionThresholds
from letspi.physics.goals import NEUTRAL_LANE_FACTOR, NEUTRAL_LON_FACTOR
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.params import PARAM_NAMES, SocialForceParams
from letspi.physics.types import NeighbourPrediction
from letspi.planners.base import PlanBatch
from letspi.planners.config import Config, GoalsConfig, LlmConfig, MemoryPhaseConfig, MemoryRef, SfParamsConfig
from letspi.planners.sf_opt import SearchSpace
from letspi.scenario.identity import scenario_digests
from letspi.scenario.types import ScenarioBatch


def _info(final: Proposal, proposals: Sequence[Proposal], extra: dict[str, float]) -> dict[str, np.ndarray]:
    """Per-scenario extras of the final proposal; calls, tokens and timing summed over ``proposals``."""

    def total(key: str) -> float:
        return float(sum(float(p.meta.get(key, 0) or 0) for p in proposals))

    calls, cached_calls = total("attempts"), total("cached_attempts")
    info = {name: np.array([float(getattr(final.params, name))]) for name in PARAM_NAMES}
    info.update({
        "lon_factor": np.array([final.lon_factor]),
        "lane_factor": np.array([final.lane_factor]),
        "llm_calls": np.array([calls]),
        "llm_cached_calls": np.array([cached_calls]),
        "llm_cached": np.array([calls > 0 and cached_calls == calls]),
        "llm_latency_s": np.array([total("uncached_latency_s")]),
        "llm_original_latency_s": np.array([total("original_latency_s")]),
        "prompt_tokens": np.array([total("prompt_tokens")]),
        "completion_tokens": np.array([total("completion_tokens")]),
        "fallback": np.array([final.fallback]),
        "any_fallback": np.array([any(p.fallback for p in proposals)]),
        "n_clamped": np.array([len(final.clamped_fields)]),
    })
    info.update({k: np.array([v]) for k, v in extra.items()})
    return info


SF_SOURCE = -1  # shield_source of the fitted sf parameters
GRID_SOURCE = -2  # shield_source of a candidate of sf-opt's grid
Alternative = tuple[int, SocialForceParams, float, float]  # (shield_source, params, lon_factor, lane_factor)


@dataclass(frozen=True)
class ShieldResult:
    """The plan to return (F, 2 each), its goal (2,) and the info columns of the shield."""

    xy_m: np.ndarray
    vxy_mps: np.ndarray
    goal_xy_m: np.ndarray
    shielded: bool
    safe: bool
    source: int
    params: SocialForceParams
    lon_factor: float
    lane_factor: float

    def info(self) -> dict[str, float]:
        return {"shielded": float(self.shielded), "shield_checked": 1.0, "shield_safe": float(self.safe),
                "shield_source": float(self.source)}


def _severity(report: SafetyReport) -> tuple[float, ...]:
    """Smaller is less unsafe: contact, off-road, number of violations, then (negated) margins."""
    m = report.metrics
    ttc = min(m["min_ttc_s"], m["min_rear_ttc_s"], 10.0)
    return (m["collision"], m["off_road"], float(len(report.violations)), -ttc, -min(m["min_path_gap_m"], 50.0))


def shield_plan(
    scenario: ScenarioBatch,
    plan_xy_m: np.ndarray,
    plan_vxy_mps: np.ndarray,
    goal_xy_m: np.ndarray,
    proposal: Proposal,
    alternatives: list[Alternative],
    base_goal_xy_m: np.ndarray,
    prediction: NeighbourPrediction,
    thresholds: ReflectionThresholds,
) -> ShieldResult:
    """Check the plan (F, 2) of ``proposal`` against the predicted neighbours; replace it by the safest
    alternative when it fails.

    alternatives: (source, params, lon_factor, lane_factor) tried in order (first safe one wins);
    all are simulated and checked in one batch, and only when the plan fails.
    """
    report = safety_report(scenario, plan_xy_m[None], plan_vxy_mps[None], prediction, thresholds)[0]
    keep = ShieldResult(plan_xy_m, plan_vxy_mps, np.asarray(goal_xy_m, dtype=np.float64), False, report.safe, 0,
                        proposal.params, proposal.lon_factor, proposal.lane_factor)
    if report.safe or not alternatives:
        return keep
    k = len(alternatives)
    one = scenario.take(np.zeros(k, dtype=np.int64))
    pred_k = NeighbourPrediction(*(np.repeat(np.asarray(a), k, axis=0) for a in prediction))
    sim = simulate_proposal(one, SocialForceParams.stack([a[1] for a in alternatives]),
                            np.array([a[2] for a in alternatives]), np.array([a[3] for a in alternatives]),
                            np.repeat(np.asarray(base_goal_xy_m, dtype=np.float64).reshape(1, 2), k, axis=0), pred_k)
    reports = safety_report(one, sim.xy_m, sim.vxy_mps, pred_k, thresholds)
    safe = [i for i, r in enumerate(reports) if r.safe]
    if safe:
        best = safe[0]
    else:
        best = min(range(k), key=lambda i: _severity(reports[i]))
        if _severity(reports[best]) >= _severity(report):
            return keep  # nothing is less unsafe than the LLM's own plan
    src, params, lon, lane = alternatives[best]
    return ShieldResult(sim.xy_m[best], sim.vxy_mps[best], sim.goals_xy_m[best], True, reports[best].safe, src,
                        params, lon, lane)


def sf_alternatives(params: SocialForceParams, space: SearchSpace | None = None) -> list[Alternative]:
    """The fitted parameters with the neutral goal, then ``sf-opt``'s grid around them, cheapest first
    (``SearchSpace`` cost: goal change, lane change, stronger repulsion)."""
    space = space or SearchSpace()
    grid = space.grid()
    cost = (np.abs(grid[:, 1] - NEUTRAL_LON_FACTOR) + space.lane_change_cost * np.abs(grid[:, 2])
            + space.k_scale_cost * (grid[:, 0] - 1.0))
    out: list[Alternative] = [(SF_SOURCE, params, NEUTRAL_LON_FACTOR, NEUTRAL_LANE_FACTOR)]
    for k_scale, lon, lane in grid[np.argsort(cost, kind="stable")]:
        if k_scale == 1.0 and lon == NEUTRAL_LON_FACTOR and lane == NEUTRAL_LANE_FACTOR:
            continue  # the fitted parameters themselves, already first
        scaled = replace(params, k_np=params.k_np * k_scale, k_nf=params.k_nf * k_scale, k_nl=params.k_nl * k_scale)
        out.append((GRID_SOURCE, scaled, float(lon), float(lane)))
    return out


_UNSHIELDED = {"shielded": 0.0, "shield_checked": 0.0, "shield_safe": float("nan"), "shield_source": 0.0}


@dataclass
class LetsPiMemoryPlanner:
    """The memory-collection phase as a planner; optionally stores each experience in ``bank``.

    ``phase.thresholds.max_iterations == 0`` makes it the single-shot ``llm`` planner (and the
    "w/o reflection" ablation); ``phase.goal_adjustment = False`` the "w/o goal adjustment" one.
    """

    phase: MemoryPhase
    bank: MemoryBank | None = None
    shield_params: SocialForceParams | None = None  # the fitted sf parameters; None = no shield
    name: str = "letspi-memory"
    batch_size: int = 1
    reads_future: bool = False
    last_iterations: tuple[IterationRecord, ...] = ()

    @property
    def advisor(self) -> ParamAdvisor:
        return self.phase.advisor

    @property
    def concurrent_safe(self) -> bool:
        """Without a ``bank``: storing inside ``plan`` would follow completion order, not scenario order."""
        return self.bank is None

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        if len(batch) != 1:
            raise ValueError(f"{self.name} plans one scenario per call, got {len(batch)}")
        result = self.phase.run(batch)
        if self.bank is not None:
            self.bank.add(self.phase.experience(batch, result, str(scenario_digests(batch)[0])))
        self.last_iterations = result.iterations
        final = result.final
        validated = result.validated and not final.proposal.fallback
        extra = {"iterations": float(len(result.iterations)), "validated": float(validated), **_UNSHIELDED}
        xy, vxy, goal = final.plan_xy_m, final.plan_vxy_mps, np.asarray(final.goal_xy_m, dtype=np.float64)
        if self.shield_params is not None:
            # the reflection loop already checked the final plan against the same prediction
            base_goal = self.phase.goal_predictor.predict_goals(batch).top[0]
            pred = predict_neighbours(batch, self.phase.neighbour_mode)
            shield = shield_plan(batch, xy, vxy, goal, final.proposal, sf_alternatives(self.shield_params),
                                 base_goal, pred, self.phase.thresholds)
            xy, vxy, goal = shield.xy_m, shield.vxy_mps, shield.goal_xy_m
            extra.update(shield.info())
        info = _info(final.proposal, [it.proposal for it in result.iterations], extra)
        return PlanBatch(xy_m=np.asarray(xy, dtype=np.float64)[None], vxy_mps=np.asarray(vxy, dtype=np.float64)[None],
                         goals_xy_m=goal.reshape(1, 2), info=info)


@dataclass
class LetsPiFastPlanner:
    """The fast-inference phase: retrieved memories as few-shot examples, one call, no reflection."""

    phase: FastPhase
    neighbour_mode: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    shield_params: SocialForceParams | None = None  # the fitted sf parameters; None = no shield
    thresholds: ReflectionThresholds = field(default_factory=ReflectionThresholds)
    name: str = "letspi-fast"
    batch_size: int = 1
    reads_future: bool = False
    last_retrieved: tuple[tuple[str, float], ...] = ()
    last_proposal: Proposal | None = None
    concurrent_safe: bool = True

    @property
    def advisor(self) -> ParamAdvisor:
        return self.phase.advisor

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        if len(batch) != 1:
            raise ValueError(f"{self.name} plans one scenario per call, got {len(batch)}")
        base_goal = self.phase.goal_predictor.predict_goals(batch).top
        proposal, retrieved = self.phase.propose(batch, base_goal[0])
        proposal = proposal.normalised()
        self.last_retrieved, self.last_proposal = tuple(retrieved), proposal
        pred = predict_neighbours(batch, self.neighbour_mode)
        sim = simulate_proposal(
            batch, SocialForceParams.stack([proposal.params]), np.array([proposal.lon_factor]),
            np.array([proposal.lane_factor]), base_goal, pred,
        )
        extra = {"n_retrieved": float(len(retrieved)),
                 "top_similarity": float(retrieved[0][1]) if retrieved else float("nan"), **_UNSHIELDED}
        if self.shield_params is None:
            info = _info(proposal, [proposal], extra)
            return PlanBatch(xy_m=sim.xy_m, vxy_mps=sim.vxy_mps, goals_xy_m=sim.goals_xy_m, info=info)
        shield = shield_plan(batch, sim.xy_m[0], sim.vxy_mps[0], sim.goals_xy_m[0], proposal,
                             [*self._memory_alternatives(batch), *sf_alternatives(self.shield_params)],
                             base_goal[0], pred, self.thresholds)
        extra.update(shield.info())
        info = _info(proposal, [proposal], extra)
        return PlanBatch(xy_m=shield.xy_m[None], vxy_mps=shield.vxy_mps[None], goals_xy_m=shield.goal_xy_m[None],
                         info=info)

    def _memory_alternatives(self, batch: ScenarioBatch) -> list[Alternative]:
        """The retrieved memories' parameters (retrieval is repeated here: milliseconds, bank reads only)."""
        retriever = self.phase.retriever
        if retriever is None:
            return []
        return [(k + 1, e.params, float(e.lon_factor), float(e.lane_factor))
                for k, (e, _) in enumerate(retriever.retrieve(batch))]


class MemoryPlannerConfig(Config):
    """``llm`` (single shot: ``phase.reflection.max_iterations`` = 0) or ``letspi-memory``.

    ``shield``: the safety shield (beyond the paper) replaces a plan that fails the reflection checks
    by the fitted ``sf`` plan when that is safer. Not part of the phase: the stored experiences are
    the same with and without it.
    """

    kind: Literal["llm", "letspi-memory"] = "letspi-memory"
    phase: MemoryPhaseConfig
    shield: bool = True


class FastPlannerConfig(Config):
    """``letspi-fast`` (top-k retrieved memories) or ``letspi-fs`` (three static examples)."""

    kind: Literal["letspi-fast", "letspi-fs"] = "letspi-fast"
    llm: LlmConfig
    goals: GoalsConfig
    neighbours: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    sf_params: SfParamsConfig
    memory: MemoryRef
    top_k: int = Field(default=TOP_K, ge=0)
    shield: bool = True  # the safety shield (retrieved memories' parameters, then the fitted sf)
