"""LLM planners: ``llm`` (single shot), ``letspi-memory`` (memory collection with reflection), ``letspi-fast``
(retrieved memories) and ``letspi-fs`` (three static examples instead of retrieval).

``propose`` makes one scenario's LLM calls and is thread-safe; ``simulate`` rolls out and shields every proposal
at once. The safety shield (beyond the paper; ``--no-shield``: the ablation) replaces a plan failing the
reflection checks against the prediction by the first safe alternative (presets, retrieved memories, the fitted
``sf`` parameters, ``sf-opt``'s grid), else the least unsafe; it leaves the decision step's presets alone unless
``--shield-presets``.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from letspi.keyed import Config
from letspi.llm.client import ParamAdvisor, RetryPolicy
from letspi.llm.compact import PROMPT_STYLES
from letspi.llm.config import LlmConfig
from letspi.method.choosers import CHOOSER_NAMES, MODEL_CHOOSER, Chooser, load_teacher, make_chooser, uses_model
from letspi.method.config import DecisionConfig, MemoryPhaseConfig, MemoryRef
from letspi.method.decide import CUSTOM, DEFAULT_NAME, Decider, params_of, preference_order
from letspi.method.matching import TOP_K
from letspi.method.memory import Experience, MemoryBank
from letspi.method.phases import FastPhase, MemoryPhase
from letspi.method.reflection import (
    IterationRecord,
    Proposal,
    ReflectionResult,
    SafetyReport,
    SimulatedPlan,
    safety_report,
    simulate_proposal,
)
from letspi.method.thresholds import MAX_ITERATIONS, ReflectionThresholds
from letspi.metrics.registry import Agg, Metric
from letspi.physics.goals import NEUTRAL_LANE_FACTOR, NEUTRAL_LON_FACTOR
from letspi.physics.idm import rollout_idm_ego
from letspi.physics.neighbours import NeighbourPredictionMode
from letspi.physics.params import PARAM_NAMES, SocialForceParams
from letspi.planners.base import PlanBatch, PlanningContext, Proposals, plan_by_proposals, predicted_context
from letspi.planners.config import SOCIAL_FORCE_OPTIONS, GoalsConfig, SfParamsConfig
from letspi.planners.decision import (
    ADVERSE,
    DECIDE,
    DECISION_OPTIONS,
    DECISION_OUTPUTS,
    PRESETS,
    RISK_MODEL,
    adverse_failed_names,
    decision_info,
)
from letspi.planners.idm import settle_laterally
from letspi.planners.options import DECISION_PANEL, LLM_PANEL, PlannerOption, file_option
from letspi.planners.outputs import LANE_FACTOR, LON_FACTOR, PARAM_OUTPUTS, output
from letspi.planners.sf_opt import SearchSpace, search_order
from letspi.scenario.identity import scenario_digests
from letspi.scenario.types import ScenarioBatch

DEFAULT_LLM = "llamacpp:smollm2-135m-letspi"
DEFAULT_FAST_LLM = "llamacpp:smollm2-135m-letspi"

# Options of the LLM planners and of memory collection ------------------------------------------------
LLM = PlannerOption(
    "llm", str, DEFAULT_LLM, "Model of llm / letspi-memory and of memory collection (spec, e.g. "
    "llamacpp:smollm2-135m, ollama:llama3.1:8b, openai:MODEL@http://host:port/v1)", panel=LLM_PANEL)
FAST_LLM = PlannerOption("fast_llm", str, DEFAULT_FAST_LLM, "Model of letspi-fast / letspi-fs (a spec as for --llm)",
                         panel=LLM_PANEL)
PROMPT_STYLE = PlannerOption[str | None](
    "prompt_style", str | None, None,
    "Prompt style of the LLM planners and memory collection (paper: the physics-informed prompt with few-shot "
    "memories; compact: eight numbers from a short prompt; choice: one of the decision step's checked presets); "
    "default: the style a fine-tuned embedded model was trained on (its manifest; the shipped one: choice), "
    "else paper", choices=PROMPT_STYLES, panel=LLM_PANEL)
LLM_CACHE = PlannerOption("llm_cache", bool, True, "Persistent LLM response cache (cached rows are excluded from "
                          "the inference time)", flag="--cache", panel=LLM_PANEL)
LLM_TIMEOUT = PlannerOption(
    "llm_timeout_s", float, RetryPolicy.timeout_s,
    "Time one LLM request may take (5 s to connect); a timeout is retried with backoff. Requests queued behind a "
    "server's busy slots count against it", unit="s", flag="--request-timeout", panel=LLM_PANEL)
MAX_REFINEMENTS = PlannerOption("max_iterations", int, MAX_ITERATIONS,
                                "Reflection refinements of letspi-memory and of memory collection (0: none)",
                                panel=LLM_PANEL)
GOAL_ADJUSTMENT = PlannerOption("goal_adjustment", bool, True, "Let the LLM adjust goals (off: the 'w/o GA' "
                                "ablation)", panel=LLM_PANEL)
MEMORY = file_option("memory", "Memory bank (from `letspi collect`) of letspi-fast / letspi-fs", panel=LLM_PANEL)
MEMORY_KEY = PlannerOption[str | None]("memory_key", str | None, None, "Only memories collected under this "
                                       "configuration key (default: all in the bank)", panel=LLM_PANEL)
TOP_K_OPTION = PlannerOption("top_k", int, TOP_K, "Memories retrieved per scenario by letspi-fast", panel=LLM_PANEL)
ALLOW_SAME_VEHICLE = PlannerOption("allow_same_vehicle", bool, False, "Let retrieval return memories of the "
                                   "query's own vehicle or overlapping windows (a leak)", panel=LLM_PANEL)
MEMORY_FRACTION = PlannerOption[float | None](
    "memory_fraction", float | None, None,
    "Memory-size ablation: retrieve from a reproducible subset of this fraction of the memories (default: all)",
    panel=LLM_PANEL)
MEMORY_SEED = PlannerOption("memory_seed", int, 0, "Seed of the --memory-fraction subset", panel=LLM_PANEL)
SHIELD = PlannerOption(
    "shield", bool, True,
    "Safety shield of the LLM planners (beyond the paper): a plan failing the reflection checks against the "
    "predicted neighbours is replaced by the safest of the retrieved memories' and the fitted sf parameters; "
    "--no-shield: the paper-faithful ablation", panel=LLM_PANEL)
SHIELD_PRESETS = PlannerOption(
    "shield_presets", bool, False,
    "Decision step of letspi-fast and sf-check: the shield may replace the preset the decision step planned too "
    "(off: the decision step's checks against the prediction and the adverse futures stand in for it, and where "
    "the defaults are kept the planner plans exactly as sf)", panel=DECISION_PANEL)
#: what memory collection reads (``Resolver.memory_phase``)
MEMORY_PHASE_OPTIONS: tuple[PlannerOption[Any], ...] = (
    LLM, PROMPT_STYLE, LLM_CACHE, LLM_TIMEOUT, MAX_REFINEMENTS, GOAL_ADJUSTMENT, DECIDE, PRESETS, ADVERSE, RISK_MODEL,
    *SOCIAL_FORCE_OPTIONS)
#: ``llm``: single shot (no refinements)
SINGLE_SHOT_OPTIONS: tuple[PlannerOption[Any], ...] = (
    *(o for o in MEMORY_PHASE_OPTIONS if o is not MAX_REFINEMENTS), SHIELD)
MEMORY_PLANNER_OPTIONS: tuple[PlannerOption[Any], ...] = (*MEMORY_PHASE_OPTIONS, SHIELD)
CHOOSER = PlannerOption(
    "chooser", str, MODEL_CHOOSER,
    "What picks the preset where letspi-fast's risk gate fires, under the same presets, checks, gate, verification "
    "and shield: model (the LLM), shuffled (the LLM answering another window's prompt), or, with no model, rule "
    "(sf-check's), constant-default, constant-ease, cautious (the rule, ties broken towards slowing down), teacher "
    "(the expected-utility policy that made the model's labels)", choices=CHOOSER_NAMES, panel=DECISION_PANEL)
TEACHER = file_option("teacher_file", "Trees of --chooser teacher (from `letspi train decide`; default: the shipped "
                      "ones)", flag="--teacher", panel=DECISION_PANEL)
FAST_OPTIONS: tuple[PlannerOption[Any], ...] = (
    FAST_LLM, PROMPT_STYLE, LLM_CACHE, LLM_TIMEOUT, MEMORY, MEMORY_KEY, TOP_K_OPTION, ALLOW_SAME_VEHICLE,
    MEMORY_FRACTION, MEMORY_SEED, SHIELD, SHIELD_PRESETS, CHOOSER, TEACHER, *DECISION_OPTIONS, *SOCIAL_FORCE_OPTIONS)


LLM_CACHED = output("llm_cached", "bool", "bool", "every model call of the scenario was served by the response "
                    "cache (its time is a lookup: left out of inference_s)")
LLM_CALLS = output("llm_calls", "n", "float64", "model calls made for the scenario",
                   Agg("llm_calls_per_scenario", "finite_mean", "model calls per scenario"))
LLM_ORIGINAL_LATENCY = output("llm_original_latency_s", "s", "float64", "what the scenario's calls cost when first "
                              "made (cached replies included)", Agg("llm_original_latency_s", "finite_mean"))
FALLBACK = output("fallback", "bool", "bool", "the final plan uses the fallback parameters (no valid answer)",
                  Agg("fallback_pct", "pct", "share of scenarios planned with the fallback parameters"))
#: what every LLM planner reports (``_info``)
LLM_OUTPUTS: tuple[Metric, ...] = (
    *PARAM_OUTPUTS, LON_FACTOR, LANE_FACTOR, LLM_CALLS,
    output("llm_cached_calls", "n", "float64", "model calls the response cache served"),
    LLM_CACHED,
    output("llm_latency_s", "s", "float64", "wall time of the calls that ran the model now"),
    LLM_ORIGINAL_LATENCY,
    output("prompt_tokens", "n", "float64", "prompt tokens of the scenario's calls"),
    output("completion_tokens", "n", "float64", "completion tokens of the scenario's calls"),
    FALLBACK,
    output("any_fallback", "bool", "bool", "some proposal of the scenario fell back"),
    output("n_clamped", "n", "int64", "fields of the final answer clamped into their ranges"),
)
#: the memory phase (``llm``, ``letspi-memory``): its reflection
MEMORY_OUTPUTS: tuple[Metric, ...] = (
    output("iterations", "n", "float64", "proposals made (1 + refinements)"),
    output("validated", "bool", "float64", "1 when the final plan passed the reflection's checks, else 0"),
)
#: the fast phase (``letspi-fast``, ``letspi-fs``): its retrieval
FAST_OUTPUTS: tuple[Metric, ...] = (
    output("n_retrieved", "n", "float64", "memories retrieved for the fast prompt"),
    output("top_similarity", "1", "float64", "similarity of the best retrieved memory"),
)


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
PRESET_SOURCE = -3  # shield_source of a preset of the decision step (``letspi.method.decide``)
IDM_SOURCE = -4  # shield_source of the IDM plan (``--idm-fallback``)
Alternative = tuple[int, SocialForceParams, float, float]  # (shield_source, params, lon_factor, lane_factor)
#: ``Proposals.extra`` key of letspi-fast: (B, K, 9) the retrieved memories' parameters (``PARAM_NAMES``
#: order), lon_factor and lane_factor, best first; NaN rows where fewer than K were retrieved
MEMORY_ALTERNATIVES = "memory_alternatives"
_ALTERNATIVE_COLUMNS = len(PARAM_NAMES) + 2
#: alternatives per failing plan simulated first (the retrieved memories and the fitted parameters)
SHIELD_FIRST_STAGE = 4


SHIELDED = output("shielded", "bool", "float64", "1 when the safety shield replaced the plan, else 0",
                  Agg("shielded_pct", "pct", "share of plans the safety shield replaced"))
#: what the safety shield records (``ShieldedPlans.info``)
SHIELD_OUTPUTS: tuple[Metric, ...] = (
    SHIELDED,
    output("shield_checked", "bool", "float64", "1 when the shield checked the plan"),
    output("shield_safe", "bool", "float64", "1 when the returned plan passes the checks (NaN: not checked)"),
    output("shield_source", "code", "float64", "where the returned plan came from: its own (0), a memory (k >= 1), "
           "the fitted sf parameters (-1), sf-opt's grid (-2), a preset (-3) or the IDM fallback (-4)"),
)
#: what the memory-phase planners (``llm``, ``letspi-memory``) and the fast ones (``letspi-fast``, ``letspi-fs``)
#: report; the decision outputs only with the decision step
MEMORY_PLANNER_OUTPUTS: tuple[Metric, ...] = (*LLM_OUTPUTS, *MEMORY_OUTPUTS, *SHIELD_OUTPUTS, *DECISION_OUTPUTS)
FAST_PLANNER_OUTPUTS: tuple[Metric, ...] = (*LLM_OUTPUTS, *FAST_OUTPUTS, *SHIELD_OUTPUTS, *DECISION_OUTPUTS)


@dataclass(frozen=True)
class ShieldedPlans:
    """The plans to return, (B, F, 2) each, their goals (B, 2), and per scenario whether the shield
    replaced the plan, whether the returned plan passes the checks and where it came from."""

    xy_m: np.ndarray
    vxy_mps: np.ndarray
    goals_xy_m: np.ndarray
    shielded: np.ndarray
    safe: np.ndarray
    source: np.ndarray

    def info(self) -> dict[str, np.ndarray]:
        b = len(self.shielded)
        return {"shielded": self.shielded.astype(np.float64), "shield_checked": np.ones(b),
                "shield_safe": self.safe.astype(np.float64), "shield_source": self.source.astype(np.float64)}


def shield_plans(batch: ScenarioBatch, plans_xy_m: np.ndarray, plans_vxy_mps: np.ndarray, goals_xy_m: np.ndarray,
                 alternatives: Sequence[Sequence[Alternative]], context: PlanningContext,
                 thresholds: ReflectionThresholds, *, first_stage: int = SHIELD_FIRST_STAGE,
                 reports: Sequence[SafetyReport] | None = None) -> ShieldedPlans:
    """Check B plans (B, F, 2) against the predicted neighbours; replace each failing one by the first safe of
    its ``alternatives[i]`` (source, params, lon_factor, lane_factor), else the least unsafe if less unsafe than
    the plan (checked in two stages: the first ``first_stage``, then the rest where none was safe). Factors
    apply to ``context.goals_xy_m``; ``goals_xy_m`` (B, 2): the plans'."""
    b = len(batch)
    if reports is None:  # the plans' own reports (the caller may have them already)
        reports = safety_report(batch, plans_xy_m, plans_vxy_mps, context.neighbours, thresholds)
    xy = np.array(plans_xy_m, dtype=np.float64)
    vxy = np.array(plans_vxy_mps, dtype=np.float64)
    goals = np.array(goals_xy_m, dtype=np.float64).reshape(b, 2)
    shielded = np.zeros(b, dtype=bool)
    safe = np.array([r.safe for r in reports], dtype=bool)
    source = np.zeros(b, dtype=np.int64)
    # per failing scenario: every alternative checked so far, as (alternative index, plan, report)
    tried: dict[int, list[tuple[int, np.ndarray, np.ndarray, np.ndarray, SafetyReport]]] = {
        i: [] for i in range(b) if not reports[i].safe and alternatives[i]}
    for lo, hi in ((0, first_stage), (first_stage, None)):
        todo = [(i, j) for i in tried if not any(t[4].safe for t in tried[i])
                for j in range(len(alternatives[i]))[lo:hi]]
        if not todo:
            continue
        rows = np.array([i for i, _ in todo])
        chosen = [alternatives[i][j] for i, j in todo]
        big, big_context = batch.take(rows), context.take(rows)
        sim = simulate_proposal(big, SocialForceParams.stack([a[1] for a in chosen]),
                                np.array([a[2] for a in chosen]), np.array([a[3] for a in chosen]),
                                big_context.goals_xy_m, big_context.neighbours)
        checked = safety_report(big, sim.xy_m, sim.vxy_mps, big_context.neighbours, thresholds)
        for r, (i, j) in enumerate(todo):
            tried[i].append((j, sim.xy_m[r], sim.vxy_mps[r], sim.goals_xy_m[r], checked[r]))
    for i, options in tried.items():
        first_safe = next((t for t in options if t[4].safe), None)
        if first_safe is None:
            best = min(options, key=lambda t: t[4].severity())  # all were checked; ties: the earlier
            if best[4].severity() >= reports[i].severity():
                continue  # nothing is less unsafe than the plan itself
        else:
            best = first_safe
        j, xy[i], vxy[i], goals[i] = best[0], best[1], best[2], best[3]
        shielded[i], safe[i], source[i] = True, best[4].safe, alternatives[i][j][0]
    return ShieldedPlans(xy, vxy, goals, shielded, safe, source)


def idm_fallback(batch: ScenarioBatch, context: PlanningContext, shield: ShieldedPlans,
                 thresholds: ReflectionThresholds) -> ShieldedPlans:
    """Where the plan still fails the shield's checks (a kept preset's too), the ``idm`` planner's plan among the
    same predicted neighbours replaces it if it fails less (IDM brakes by gap and closing speed in time)."""
    rows = np.flatnonzero(~shield.safe)
    if rows.size == 0:
        return shield
    sub, sub_context = batch.take(rows), context.take(rows)
    roll = rollout_idm_ego(sub, sub_context.neighbours)
    idm_xy, idm_vxy = np.array(roll.xy_m, dtype=np.float64), np.array(roll.vxy_mps, dtype=np.float64)
    idm_xy[..., 1], idm_vxy[..., 1] = settle_laterally(sub)
    current = safety_report(sub, shield.xy_m[rows], shield.vxy_mps[rows], sub_context.neighbours, thresholds)
    idm = safety_report(sub, idm_xy, idm_vxy, sub_context.neighbours, thresholds)
    better = np.array([i.safe or i.severity() < c.severity() for i, c in zip(idm, current, strict=True)], dtype=bool)
    if not better.any():
        return shield
    xy, vxy = shield.xy_m.copy(), shield.vxy_mps.copy()
    shielded, safe, source = shield.shielded.copy(), shield.safe.copy(), shield.source.copy()
    take = rows[better]
    xy[take], vxy[take] = idm_xy[better], idm_vxy[better]
    shielded[take], source[take] = True, IDM_SOURCE
    safe[take] = [r.safe for r, b in zip(idm, better, strict=True) if b]
    return ShieldedPlans(xy, vxy, shield.goals_xy_m, shielded, safe, source)


def sf_alternatives(params: SocialForceParams, space: SearchSpace | None = None) -> list[Alternative]:
    """The fitted parameters with the neutral goal, then ``sf-opt``'s grid around them, cheapest first."""
    space = space or SearchSpace()
    out: list[Alternative] = [(SF_SOURCE, params, NEUTRAL_LON_FACTOR, NEUTRAL_LANE_FACTOR)]
    for k_scale, lon, lane in space.grid()[search_order(space)]:
        if k_scale == 1.0 and lon == NEUTRAL_LON_FACTOR and lane == NEUTRAL_LANE_FACTOR:
            continue  # the fitted parameters themselves, already first
        scaled = replace(params, k_np=params.k_np * k_scale, k_nf=params.k_nf * k_scale, k_nl=params.k_nl * k_scale)
        out.append((GRID_SOURCE, scaled, float(lon), float(lane)))
    return out


def pack_memory_alternatives(retrieved: Sequence[tuple[Experience, float]], k: int) -> np.ndarray:
    """The retrieved memories' parameters and goal factors as one (1, k, 9) row of ``MEMORY_ALTERNATIVES``."""
    out = np.full((1, k, _ALTERNATIVE_COLUMNS), np.nan)
    for j, (e, _) in enumerate(retrieved[:k]):
        out[0, j] = [*e.params.as_array(), float(e.lon_factor), float(e.lane_factor)]
    return out


def memory_alternatives(row: np.ndarray) -> list[Alternative]:
    """``pack_memory_alternatives``' row (k, 9) back as alternatives (source = rank + 1)."""
    out: list[Alternative] = []
    for j, values in enumerate(np.asarray(row, dtype=np.float64).reshape(-1, _ALTERNATIVE_COLUMNS)):
        if np.isnan(values).all():
            continue
        params = SocialForceParams.from_mapping(dict(zip(PARAM_NAMES, values[: len(PARAM_NAMES)], strict=True)))
        out.append((j + 1, params, float(values[-2]), float(values[-1])))
    return out


_UNSHIELDED = {"shielded": 0.0, "shield_checked": 0.0, "shield_safe": float("nan"), "shield_source": 0.0}


def fitted_proposal(advisor: ParamAdvisor, r_col_m: float) -> Proposal:
    """The advisor's fallback reply (the fitted ``sf`` parameters, neutral goal) as a proposal without a call."""
    reply = advisor.fallback_reply
    return Proposal(params=SocialForceParams(**reply.params(), r_col_m=r_col_m), lon_factor=reply.lon_factor,
                    lane_factor=reply.lane_factor, rationale="no LLM answer in force: the fitted parameters")


def _one(batch: ScenarioBatch, i: int) -> ScenarioBatch:
    return batch if len(batch) == 1 else batch.take([i])


_Row = tuple[Proposal, dict[str, np.ndarray], dict[str, np.ndarray]]  # (final proposal, info, extra) of one scenario


def _proposals(rows: Sequence[_Row]) -> Proposals:
    """(final proposal, info of one row, extra of one row) per scenario -> ``Proposals``."""
    return Proposals(
        params=SocialForceParams.stack([p.params for p, _, _ in rows]),
        lon_factor=np.array([p.lon_factor for p, _, _ in rows], dtype=np.float64),
        lane_factor=np.array([p.lane_factor for p, _, _ in rows], dtype=np.float64),
        info={k: np.concatenate([info[k] for _, info, _ in rows]) for k in rows[0][1]},
        extra={k: np.concatenate([extra[k] for _, _, extra in rows]) for k in rows[0][2]},
    )


@dataclass
class LetsPiMemoryPlanner:
    """The memory-collection phase as a planner, storing each experience in ``bank`` if given;
    ``max_iterations == 0`` makes it the single-shot ``llm`` planner (the "w/o reflection" ablation)."""

    phase: MemoryPhase
    bank: MemoryBank | None = None
    shield_params: SocialForceParams | None = None  # the fitted sf parameters; None = no shield
    name: str = "letspi-memory"
    batch_size: int = 64
    last_iterations: tuple[IterationRecord, ...] = ()
    proposes_per_scenario: bool = True

    @property
    def advisor(self) -> ParamAdvisor:
        return self.phase.advisor

    @property
    def concurrent_safe(self) -> bool:
        """Without a ``bank``: storing inside ``plan`` would follow completion order, not scenario order."""
        return self.bank is None

    def context(self, batch: ScenarioBatch) -> PlanningContext:
        return predicted_context(batch, self.phase.goal_predictor, self.phase.neighbour_mode)

    def propose(self, batch: ScenarioBatch, context: PlanningContext) -> Proposals:
        rows: list[_Row] = []
        for i in range(len(batch)):
            one = _one(batch, i)
            own = context.take([i])
            result = self.phase.run(one, own.goals_xy_m[0], own.neighbours)
            if self.bank is not None:
                self.bank.add(self.phase.experience(one, result, str(scenario_digests(one)[0])))
            self.last_iterations = result.iterations
            final = result.final.proposal
            validated = result.validated and not final.fallback
            extra = {"iterations": float(len(result.iterations)), "validated": float(validated), **_UNSHIELDED}
            info = _info(final, [it.proposal for it in result.iterations], extra)
            if self.phase.decider is not None:
                first = result.iterations[0].adverse
                info.update(decision_info([str(final.meta.get("decision", CUSTOM))], np.ones(1, bool),
                                          np.full(1, np.nan), np.array([float(result.n_refinements)]),
                                          [reflection_trail(result)]))
                info["adverse_failed"] = np.array([",".join(first.failed) if first is not None else ""], dtype=object)
            rows.append((final, info, {}))
        return _proposals(rows)

    def default_proposals(self, batch: ScenarioBatch) -> Proposals:
        """What is in force before any LLM answer (closed loop, dual rate): the fitted parameters."""
        p = fitted_proposal(self.phase.advisor, self.phase.r_col_m)
        extra = {"iterations": 0.0, "validated": 0.0, **_UNSHIELDED}
        info = _info(p, [], extra)
        if self.phase.decider is not None:
            info.update(_default_decision())
        return _proposals([(p, info, {})] * len(batch))

    def simulate(self, batch: ScenarioBatch, context: PlanningContext, proposals: Proposals) -> PlanBatch:
        return simulate_and_shield(batch, context, proposals, self.shield_params, self.phase.thresholds,
                                   with_memories=False, decider=self.phase.decider)

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        return plan_by_proposals(self, batch)


@dataclass
class LetsPiFastPlanner:
    """The fast-inference phase: retrieved memories as few-shot examples, one call, no reflection. ``shuffle``
    (``--chooser shuffled``): where the gate fires the model answers the choice prompt of another window of the
    batch (the next consulted one, cyclically; else the next window), verified and planned on this window;
    the planner then proposes per batch, so a window's donor depends on its batch."""

    phase: FastPhase
    neighbour_mode: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    shield_params: SocialForceParams | None = None  # the fitted sf parameters; None = no shield
    thresholds: ReflectionThresholds = field(default_factory=ReflectionThresholds)
    name: str = "letspi-fast"
    batch_size: int = 64
    last_retrieved: tuple[tuple[str, float], ...] = ()
    last_proposal: Proposal | None = None
    concurrent_safe: bool = True
    proposes_per_scenario: bool = True
    shuffle: bool = False
    shield_presets: bool = True  # False: the shield leaves alone the presets the decision step planned

    def __post_init__(self) -> None:
        if self.shuffle:
            if self.phase.decider is None or self.phase.chooser is not None:
                raise ValueError("the shuffled-scene control needs the decision step and the model as chooser")
            self.proposes_per_scenario = False

    @property
    def advisor(self) -> ParamAdvisor | None:
        return self.phase.advisor

    def context(self, batch: ScenarioBatch) -> PlanningContext:
        return predicted_context(batch, self.phase.goal_predictor, self.neighbour_mode)

    def propose(self, batch: ScenarioBatch, context: PlanningContext) -> Proposals:
        if self.shuffle:
            return self._propose_shuffled(batch, context)
        rows: list[_Row] = []
        for i in range(len(batch)):
            own = context.take([i])
            proposal, retrieved = self.phase.propose_retrieved(_one(batch, i), context.goals_xy_m[i], own.neighbours)
            rows.append(self._row(proposal, retrieved))
        return _proposals(rows)

    def _propose_shuffled(self, batch: ScenarioBatch, context: PlanningContext) -> Proposals:
        b = len(batch)
        assessed = [self.phase.assess(_one(batch, i), context.goals_xy_m[i], context.take([i]).neighbours)
                    for i in range(b)]
        consulted = [i for i in range(b) if assessed[i].consulted]
        rows: list[_Row] = []
        for i in range(b):
            donor = None
            if assessed[i].consulted and b > 1:
                donor = (consulted[(consulted.index(i) + 1) % len(consulted)] if len(consulted) > 1
                         else (i + 1) % b)
            retrieved = self.phase.retrieve(_one(batch, i))
            proposal = self.phase.decide(assessed[i], context.goals_xy_m[i], retrieved,
                                         prompt_of=assessed[donor] if donor is not None else None)
            rows.append(self._row(proposal, retrieved))
        return _proposals(rows)

    def _row(self, proposal: Proposal, retrieved: Sequence[tuple[Experience, float]]) -> _Row:
        k = self.phase.retriever.k if self.phase.retriever is not None else 0
        proposal = proposal.normalised()
        self.last_retrieved = tuple((e.scenario_id, s) for e, s in retrieved)
        self.last_proposal = proposal
        extra = {"n_retrieved": float(len(retrieved)),
                 "top_similarity": float(retrieved[0][1]) if retrieved else float("nan"), **_UNSHIELDED}
        info = _info(proposal, [proposal], extra)
        if self.phase.decider is not None:
            m = proposal.meta
            info.update(decision_info([str(m.get("decision", CUSTOM))], np.array([bool(m.get("consulted", True))]),
                                      np.array([float(m.get("risk_score", np.nan))]), np.zeros(1),
                                      [str(m.get("reason", ""))]))
        return proposal, info, {MEMORY_ALTERNATIVES: pack_memory_alternatives(retrieved, k)}

    def default_proposals(self, batch: ScenarioBatch) -> Proposals:
        """What is in force before any LLM answer (closed loop, dual rate): the fitted parameters."""
        p = (fitted_proposal(self.phase.advisor, self.phase.r_col_m) if self.phase.advisor is not None
             else self.phase.preset_proposal(DEFAULT_NAME, "no answer in force: the fitted parameters"))
        k = self.phase.retriever.k if self.phase.retriever is not None else 0
        extra = {"n_retrieved": 0.0, "top_similarity": float("nan"), **_UNSHIELDED}
        info = _info(p, [], extra)
        if self.phase.decider is not None:
            info.update(_default_decision())
        return _proposals([(p, info, {MEMORY_ALTERNATIVES: pack_memory_alternatives([], k)})] * len(batch))

    @property
    def holds_presets(self) -> bool:
        return self.phase.decider is not None

    def release_held(self, view: ScenarioBatch, context: PlanningContext, proposals: Proposals,
                     mode: str = "checks") -> tuple[Proposals, np.ndarray]:
        """Closed loop, dual rate: a held preset (not the defaults, not a model's own numbers) gives way to the
        defaults where the scene ``view`` no longer calls for it: ``checks``: the gate would not consult or the
        defaults pass every check; ``prediction``: the defaults pass the prediction. -> (proposals, (B,) released)."""
        decider = self.phase.decider
        released = np.zeros(len(proposals), dtype=bool)
        if decider is None or "decision" not in proposals.info:
            return proposals, released
        held = np.flatnonzero([str(d) not in (DEFAULT_NAME, CUSTOM) for d in proposals.info["decision"]])
        if not held.size:
            return proposals, released
        checks = decider.gated_checks(view.take(held), context.goals_xy_m[held], context.take(held).neighbours)
        free = checks.checks.predicted_safe[:, 0] if mode == "prediction" else (
            ~checks.consulted | checks.checks.passes_all()[:, 0])
        released[held[free]] = True
        return (with_rows(proposals, released, self.default_proposals(view.take(np.flatnonzero(released))))
                if released.any() else proposals), released

    def simulate(self, batch: ScenarioBatch, context: PlanningContext, proposals: Proposals) -> PlanBatch:
        return simulate_and_shield(batch, context, proposals, self.shield_params, self.thresholds,
                                   with_memories=True, decider=self.phase.decider,
                                   shield_presets=self.shield_presets)

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        return plan_by_proposals(self, batch)


def with_rows(proposals: Proposals, rows: np.ndarray, replacement: Proposals) -> Proposals:
    """``proposals`` with the rows where ``rows`` (B,) bool is True taken from ``replacement`` (one row each, in
    order): parameters, goal factors and every ``info`` key both have; ``extra`` stays."""
    idx = np.flatnonzero(rows)
    matrix = proposals.params.as_matrix().copy()
    matrix[idx] = replacement.params.as_matrix()
    lon, lane = np.array(proposals.lon_factor, dtype=np.float64), np.array(proposals.lane_factor, dtype=np.float64)
    lon[idx], lane[idx] = replacement.lon_factor, replacement.lane_factor
    info = {}
    for key, values in proposals.info.items():
        values = np.array(values)
        if key in replacement.info:
            values = values.astype(np.result_type(values, np.asarray(replacement.info[key])))
            values[idx] = replacement.info[key]
        info[key] = values
    return Proposals(params=SocialForceParams.from_matrix(matrix), lon_factor=lon, lane_factor=lane, info=info,
                     extra=dict(proposals.extra))


def simulate_and_shield(batch: ScenarioBatch, context: PlanningContext, proposals: Proposals,
                        shield_params: SocialForceParams | None, thresholds: ReflectionThresholds, *,
                        with_memories: bool, decider: Decider | None = None,
                        shield_presets: bool = True) -> PlanBatch:
    """The LLM planners' simulate step: roll out every proposal, then (``shield_params`` given) shield it. With
    a ``decider``: info ``adverse_failed``, and the presets passing every check are the first alternatives;
    ``shield_presets`` False leaves a plan of one of the step's presets (info ``decision``) as it is."""
    if PROPOSED_XY in proposals.extra:  # rolled out by the planner already
        sim = SimulatedPlan(*(np.asarray(proposals.extra[k]) for k in (PROPOSED_XY, PROPOSED_VXY, PROPOSED_GOALS)))
    else:
        sim = simulate_proposal(batch, proposals.params, proposals.lon_factor, proposals.lane_factor,
                                context.goals_xy_m, context.neighbours)
    info = dict(proposals.info)
    if decider is not None:  # the goal factors in force (the closed loop records them per replan)
        info.setdefault("lon_factor", np.asarray(proposals.lon_factor, dtype=np.float64))
        info.setdefault("lane_factor", np.asarray(proposals.lane_factor, dtype=np.float64))
    if decider is not None and "adverse_failed" not in info:
        info["adverse_failed"] = adverse_failed_names(batch, context, sim.xy_m, sim.vxy_mps, decider.adverse)
    if shield_params is None:
        return PlanBatch(xy_m=sim.xy_m, vxy_mps=sim.vxy_mps, goals_xy_m=sim.goals_xy_m, info=info)
    reports = safety_report(batch, sim.xy_m, sim.vxy_mps, context.neighbours, thresholds)
    fallback = _sf_alternatives(shield_params)
    memories = proposals.extra.get(MEMORY_ALTERNATIVES) if with_memories else None
    kept = (np.isin(np.asarray(info.get("decision", np.full(len(batch), "")), dtype=object),
                    list(decider.presets.names))
            if decider is not None and not shield_presets else np.zeros(len(batch), dtype=bool))
    failing = [i for i, r in enumerate(reports) if not r.safe and not kept[i]]
    presets = _preset_alternatives(batch, context, decider, failing, proposals.extra) \
        if decider is not None and failing else {}
    alternatives = [[] if kept[i] else [*presets.get(i, []),
                                        *(memory_alternatives(memories[i]) if memories is not None else []),
                                        *fallback] for i in range(len(batch))]
    shield = shield_plans(batch, sim.xy_m, sim.vxy_mps, sim.goals_xy_m, alternatives, context, thresholds,
                          reports=reports)
    if decider is not None and decider.idm_fallback:
        shield = idm_fallback(batch, context, shield, thresholds)
    info.update(shield.info())
    return PlanBatch(xy_m=shield.xy_m, vxy_mps=shield.vxy_mps, goals_xy_m=shield.goals_xy_m, info=info)


#: ``Proposals.extra`` keys of a planner that checked every preset already (``sf-check``): (B, K) whether
#: each preset passes every check, and its progress [m], valid where ``PRESETS_CHECKED`` (B,) is True (all
#: scenarios without it); the shield then does not check them again
PRESETS_PASS_ALL, PRESETS_PROGRESS, PRESETS_CHECKED = "presets_pass_all", "presets_progress_m", "presets_checked"

#: ``Proposals.extra`` keys of a planner that rolled out its proposals already (``sf-check``: its checks did):
#: (B, F, 2) positions and velocities, (B, 2) adjusted goals; ``simulate_and_shield`` takes them as they are
PROPOSED_XY, PROPOSED_VXY, PROPOSED_GOALS = "proposed_xy_m", "proposed_vxy_mps", "proposed_goals_xy_m"


def _preset_alternatives(batch: ScenarioBatch, context: PlanningContext, decider: Decider,
                         rows: list[int], extra: Mapping[str, np.ndarray]) -> dict[int, list[Alternative]]:
    """Per scenario of ``rows``, the presets passing every check, most progress first (``extra``'s checks, if any)."""
    n_presets = len(decider.presets)
    passes, progress = np.zeros((len(rows), n_presets), dtype=bool), np.full((len(rows), n_presets), np.nan)
    known = np.zeros(len(rows), dtype=bool)
    if PRESETS_PASS_ALL in extra:
        known = np.asarray(extra.get(PRESETS_CHECKED, np.ones(len(batch), dtype=bool)), dtype=bool)[rows]
        passes[known] = np.asarray(extra[PRESETS_PASS_ALL])[rows][known]
        progress[known] = np.asarray(extra[PRESETS_PROGRESS])[rows][known]
    todo = np.asarray(rows, dtype=np.int64)[~known]
    if todo.size:
        checks = decider.check(batch.take(todo), context.goals_xy_m[todo], context.take(todo).neighbours)
        passes[~known], progress[~known] = checks.passes_all(), checks.progress_m
    table = decider.presets
    out: dict[int, list[Alternative]] = {}
    for j, i in enumerate(rows):
        out[i] = []
        for k in preference_order(passes[j], progress[j], decider.lane_changes):
            v = table.values[k]
            out[i].append((PRESET_SOURCE, params_of(v, decider.r_col_m).row(0), float(v[6]), float(v[7])))
    return out


def reflection_trail(result: ReflectionResult) -> str:
    """The memory phase's rounds in one line: each answer and its checks, then the model's rationale."""
    steps = []
    for it in result.iterations:
        failed = ([] if it.predicted_safe else ["predicted"]) + list(it.adverse.failed if it.adverse else ())
        verdict = f"fails {', '.join(failed)}" if failed else "passes every check"
        steps.append(f"{it.proposal.meta.get('decision', CUSTOM)}: {verdict}")
    rationale = result.final.proposal.rationale
    return " -> ".join(steps) + (f"; model: {rationale}" if rationale else "")


def _default_decision() -> dict[str, np.ndarray]:
    """The decision columns of the defaults in force before any answer (closed loop, dual rate)."""
    info = decision_info([DEFAULT_NAME], np.zeros(1, bool), np.full(1, np.nan), np.zeros(1),
                         ["no answer in force yet: the defaults"])
    info["adverse_failed"] = np.array([""], dtype=object)
    return info


@functools.lru_cache(maxsize=8)
def _sf_alternatives(params: SocialForceParams) -> tuple[Alternative, ...]:
    return tuple(sf_alternatives(params))


class MemoryPlannerConfig(Config):
    """``llm`` (single shot: ``max_iterations`` 0) or ``letspi-memory``; ``shield`` is not part of the phase."""

    kind: Literal["llm", "letspi-memory"] = "letspi-memory"
    phase: MemoryPhaseConfig
    shield: bool = True


class ChooserConfig(Config):
    """``--chooser`` other than the model: one of ``letspi.method.choosers`` (``teacher_sha256``: the teacher's
    file) or ``shuffled`` (the model on another window's prompt)."""

    cosmetic: ClassVar[frozenset[str]] = frozenset({"teacher_path"})
    omitted_when_none: ClassVar[frozenset[str]] = frozenset({"teacher_sha256"})

    name: str
    teacher_sha256: str | None = None
    teacher_path: str = "shipped"

    @field_validator("name")
    @classmethod
    def _known(cls, name: str) -> str:
        if name not in CHOOSER_NAMES or name == MODEL_CHOOSER:
            raise ValueError(f"unknown chooser {name!r} (the model is no ChooserConfig); choosers: "
                             f"{', '.join(CHOOSER_NAMES)}")
        return name

    def chooser(self) -> Chooser | None:
        """The chooser that needs no model (None for ``shuffled``: the model chooses)."""
        if uses_model(self.name):
            return None
        teacher = None
        if self.name == "teacher":
            teacher, sha = load_teacher(None if self.teacher_path == "shipped" else Path(self.teacher_path))
            if sha != self.teacher_sha256:
                raise ValueError(f"the teacher {self.teacher_path} changed since the configuration was made "
                                 f"({str(self.teacher_sha256)[:12]} -> {sha[:12]})")
        return make_chooser(self.name, teacher)


class FastPlannerConfig(Config):
    """``letspi-fast`` (top-k retrieved memories) or ``letspi-fs`` (three static examples); ``chooser`` (None: the
    model) picks the preset where the gate fires; with one that needs no model, ``llm`` is None."""

    kind: Literal["letspi-fast", "letspi-fs"] = "letspi-fast"
    llm: LlmConfig | None
    goals: GoalsConfig
    neighbours: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    sf_params: SfParamsConfig
    memory: MemoryRef
    top_k: int = Field(default=TOP_K, ge=0)
    shield: bool = True  # the safety shield (retrieved memories' parameters, then the fitted sf)
    decision: DecisionConfig | None = None  # presets, adverse futures, risk gate (None: no decision step)
    chooser: ChooserConfig | None = None
    shield_presets: bool | None = None  # False: the shield leaves the step's presets alone; None: checks every plan

    omitted_when_none: ClassVar[frozenset[str]] = frozenset({"decision", "chooser", "shield_presets"})

    @model_validator(mode="after")
    def _chooser_and_model(self) -> FastPlannerConfig:
        no_model = self.chooser is not None and not uses_model(self.chooser.name)
        if no_model != (self.llm is None):
            raise ValueError("a fast planner has a model (llm) exactly when its chooser uses one")
        if self.chooser is not None and (self.decision is None or self.kind != "letspi-fast"):
            raise ValueError("--chooser applies to letspi-fast's decision step (the choice prompt style)")
        return self
