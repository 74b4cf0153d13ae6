"""LLM planners: ``llm`` (single shot), ``letspi-memory`` (memory-collection phase with reflection),
``letspi-fast`` (fast-inference phase with retrieved memories) and ``letspi-fs`` (the FS ablation:
the fast prompt with three static examples instead of retrieval).

They plan one scenario per call (``batch_size = 1``) so the harness times each LLM call honestly.
Per-scenario extras (``PlanBatch.info``) record the LLM side: latency, tokens, fallbacks, clamps,
reflection iterations and whether the final plan was validated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from letspi.core.memory import MemoryBank
from letspi.core.phases import FastPhase, MemoryPhase
from letspi.core.reflection import IterationRecord, Proposal, simulate_proposal
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.params import PARAM_NAMES, SocialForceParams
from letspi.planners.base import PlanBatch
from letspi.scenario.types import ScenarioBatch


def _info(proposal: Proposal, llm_latency_s: float, extra: dict[str, float]) -> dict[str, np.ndarray]:
    meta = proposal.meta
    info = {name: np.array([getattr(proposal.params, name)]) for name in PARAM_NAMES}
    info.update({
        "lon_factor": np.array([proposal.lon_factor]),
        "lane_factor": np.array([proposal.lane_factor]),
        "llm_latency_s": np.array([llm_latency_s]),
        "prompt_tokens": np.array([float(meta.get("prompt_tokens", 0))]),
        "completion_tokens": np.array([float(meta.get("completion_tokens", 0))]),
        "fallback": np.array([proposal.fallback]),
        "n_clamped": np.array([len(proposal.clamped_fields)]),
    })
    info.update({k: np.array([v]) for k, v in extra.items()})
    return info


@dataclass
class LetsPiMemoryPlanner:
    """The memory-collection phase as a planner; optionally stores each experience in ``bank``.

    ``phase.thresholds.max_iterations == 0`` makes it the single-shot ``llm`` planner (and the
    "w/o reflection" ablation); ``phase.goal_adjustment = False`` the "w/o goal adjustment" one.
    """

    phase: MemoryPhase
    bank: MemoryBank | None = None
    name: str = "letspi-memory"
    batch_size: int = 1
    last_iterations: tuple[IterationRecord, ...] = ()

    @property
    def config_key(self) -> str:
        return f"memory-phase|{self.phase.config_key}|goals-{type(self.phase.goal_predictor).__name__}"

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        if len(batch) != 1:
            raise ValueError(f"{self.name} plans one scenario per call, got {len(batch)}")
        result = self.phase.run(batch)
        if self.bank is not None:
            self.bank.add(self.phase.experience(batch, result))
        self.last_iterations = result.iterations
        final = result.final
        latency = sum(float(it.proposal.meta.get("latency_s", 0.0)) for it in result.iterations)
        tokens = {
            "prompt_tokens": sum(float(it.proposal.meta.get("prompt_tokens", 0)) for it in result.iterations),
            "completion_tokens": sum(float(it.proposal.meta.get("completion_tokens", 0)) for it in result.iterations),
        }
        info = _info(final.proposal, latency, {"iterations": float(len(result.iterations)),
                                               "validated": float(result.validated)})
        info["prompt_tokens"] = np.array([tokens["prompt_tokens"]])
        info["completion_tokens"] = np.array([tokens["completion_tokens"]])
        info["fallback"] = np.array([any(it.proposal.fallback for it in result.iterations)])
        return PlanBatch(xy_m=final.plan_xy_m[None].astype(np.float64),
                         vxy_mps=final.plan_vxy_mps[None].astype(np.float64),
                         goals_xy_m=np.asarray([final.goal_xy_m], dtype=np.float64), info=info)


@dataclass
class LetsPiFastPlanner:
    """The fast-inference phase: retrieved memories as few-shot examples, one call, no reflection."""

    phase: FastPhase
    neighbour_mode: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    name: str = "letspi-fast"
    batch_size: int = 1
    last_retrieved: tuple[tuple[str, float], ...] = ()
    last_proposal: Proposal | None = None

    @property
    def config_key(self) -> str:
        r = self.phase.retriever
        memory = "none" if r is None else (
            f"k{r.k}|mem-{r.config_key or 'all'}|n{len(r.subset_ids) if r.subset_ids is not None else 'all'}")
        return (f"fast-phase|{self.phase.advisor.backend.spec}|{memory}|static{len(self.phase.static_examples)}"
                f"|goals-{type(self.phase.goal_predictor).__name__}")

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        if len(batch) != 1:
            raise ValueError(f"{self.name} plans one scenario per call, got {len(batch)}")
        base_goal = self.phase.goal_predictor.predict_goals(batch).top
        proposal, retrieved = self.phase.propose(batch, base_goal[0])
        proposal = proposal.normalised()
        self.last_retrieved, self.last_proposal = tuple(retrieved), proposal
        sim = simulate_proposal(
            batch, SocialForceParams.stack([proposal.params]), np.array([proposal.lon_factor]),
            np.array([proposal.lane_factor]), base_goal, predict_neighbours(batch, self.neighbour_mode),
        )
        info = _info(proposal, float(proposal.meta.get("latency_s", 0.0)),
                     {"n_retrieved": float(len(retrieved)),
                      "top_similarity": float(retrieved[0][1]) if retrieved else float("nan")})
        return PlanBatch(xy_m=sim.xy_m, vxy_mps=sim.vxy_mps, goals_xy_m=sim.goals_xy_m, info=info)
