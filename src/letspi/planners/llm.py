"""LLM planners: ``llm`` (single shot), ``letspi-memory`` (memory-collection phase with reflection),
``letspi-fast`` (fast-inference phase with retrieved memories) and ``letspi-fs`` (the FS ablation:
the fast prompt with three static examples instead of retrieval).

They plan one scenario per call (``batch_size = 1``) so the harness times each LLM call honestly,
and ``plan`` is thread-safe (``concurrent_safe``): the harness keeps ``--concurrency`` scenarios in
flight (``letspi.core.runner``), all asking the planner's one ``advisor``. ``last_*`` attributes
describe the most recent call to finish (for ``letspi plan``, one scenario).
Per-scenario extras (``PlanBatch.info``) record the LLM side: tokens, fallbacks, clamps, reflection
iterations, whether the final plan was validated, and the timing honesty columns:

* ``llm_calls`` / ``llm_cached_calls``: model calls made for the scenario, and how many the response
  cache served; ``llm_cached`` is True when all of them were (the row's time is then a cache lookup);
* ``llm_latency_s``: wall time of the calls that really ran the model now;
* ``llm_original_latency_s``: what every call cost when it was first made (cache hits: the latency
  recorded with the cached reply), so a fully cached rerun still reports the model's cost.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from letspi.core.memory import MemoryBank
from letspi.core.phases import FastPhase, MemoryPhase
from letspi.core.reflection import IterationRecord, Proposal, simulate_proposal
from letspi.llm.client import ParamAdvisor
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.params import PARAM_NAMES, SocialForceParams
from letspi.planners.base import PlanBatch
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
        info = _info(final.proposal, [it.proposal for it in result.iterations],
                     {"iterations": float(len(result.iterations)), "validated": float(validated)})
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
        sim = simulate_proposal(
            batch, SocialForceParams.stack([proposal.params]), np.array([proposal.lon_factor]),
            np.array([proposal.lane_factor]), base_goal, predict_neighbours(batch, self.neighbour_mode),
        )
        info = _info(proposal, [proposal],
                     {"n_retrieved": float(len(retrieved)),
                      "top_similarity": float(retrieved[0][1]) if retrieved else float("nan")})
        return PlanBatch(xy_m=sim.xy_m, vxy_mps=sim.vxy_mps, goals_xy_m=sim.goals_xy_m, info=info)
