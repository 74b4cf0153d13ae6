"""LetsPi's two phases on top of the LLM engine (paper §III-E, Figure 1).

Memory collection (``collect``): physics-informed prompt -> proposal -> simulate -> reflection rounds -> store
the experience. Fast inference (``FastPhase``): top-k similar validated memories as few-shot examples -> one
call -> simulate. The LLM chooses the paper's six parameters; ``r_col_m`` stays at the fitted ``sf`` value.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from letspi.constants import N_TOTAL
from letspi.execution.ordered import BlockCache, RunnerConfig, RunStats, RunStatus, run_ordered
from letspi.llm.choice import OptionLine, choice_check_text, render_choice_prompt
from letspi.llm.client import Advice, ParamAdvisor
from letspi.llm.compact import PromptStyle, compact_report_text, render_compact_prompt
from letspi.llm.describe import ScenarioDescription, describe_scenario
from letspi.llm.prompts import MemoryExample, render_fast_prompt, render_physics_prompt
from letspi.llm.schema import LLM_PARAM_RANGES, PlannerReply, Variant
from letspi.llm.types import Message
from letspi.method.choosers import Chooser
from letspi.method.decide import CUSTOM, DEFAULT_NAME, Decider, OptionChecks, OptionTable
from letspi.method.matching import TOP_K, top_k
from letspi.method.memory import Experience, MemoryBank, MemoryFeatures
from letspi.method.reflection import (
    AdverseOutcome,
    Proposal,
    ReflectionContext,
    ReflectionResult,
    SafetyReport,
    reflect,
)
from letspi.method.thresholds import ReflectionThresholds
from letspi.physics.goals import GoalPredictor
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.params import SocialForceParams
from letspi.physics.types import NeighbourPrediction
from letspi.scenario.features import FEATURE_NAMES, scenario_features
from letspi.scenario.identity import scenario_digests
from letspi.scenario.types import ScenarioBatch

#: scenarios whose goals and predicted neighbours ``collect`` computes in one batch (fixed positions)
CONTEXT_BLOCK = 64


def messages_text(messages: Sequence[Message]) -> str:
    """A readable transcript of a prompt (stored with experiences and shown by ``letspi plan``)."""
    return "\n\n".join(f"[{m['role']}]\n{m['content']}" for m in messages)


def proposal_from_advice(advice: Advice, messages: Sequence[Message], r_col_m: float) -> Proposal:
    reply = advice.reply
    return Proposal(params=SocialForceParams(**reply.params(), r_col_m=r_col_m), lon_factor=reply.lon_factor,
                    lane_factor=reply.lane_factor, rationale=reply.rationale, prompt=messages_text(messages),
                    reply=advice.response.text if advice.response is not None else None,
                    clamped_fields=tuple(advice.clamped), fallback=advice.fallback, meta=advice.summary())


def compact_report(report: SafetyReport) -> str:
    """A safety report as the compact refine prompt states it (the facts the labels' reports give)."""
    return compact_report_text(report.metrics, [v.metric for v in report.violations])


def _reply_values(proposal: Proposal) -> dict[str, float]:
    values = {k: float(v) for k, v in proposal.params.as_dict().items() if k in LLM_PARAM_RANGES}
    return {**values, "lon_factor": float(proposal.lon_factor), "lane_factor": float(proposal.lane_factor)}


def choice_report(report: SafetyReport, adverse: AdverseOutcome | None) -> str:
    """The choice refinement's check line for the rejected option (``predicted``, then adverse futures)."""
    failed = ([] if report.safe else ["predicted"]) + list(adverse.failed if adverse is not None else ())
    return choice_check_text(failed)


def option_lines(checks: OptionChecks, i: int) -> list[OptionLine]:
    """Scenario ``i``'s presets as the choice prompt lists them."""
    return [OptionLine(name, tuple(checks.failed_names(i, k)), float(checks.progress_m[i, k]))
            for k, name in enumerate(checks.names)]


def preset_replies(presets: OptionTable) -> dict[str, PlannerReply]:
    """Each preset as the reply it stands for (``ParamAdvisor.choose``)."""
    return {name: PlannerReply(**presets.values_of(name), rationale=f"preset {name}") for name in presets.names}


def _with_decision(proposal: Proposal, option: str, consulted: bool, risk_score: float,
                   reason: str = "") -> Proposal:
    return replace(proposal, meta={**proposal.meta, "decision": option, "consulted": consulted,
                                   "risk_score": risk_score, "reason": reason})


def decision_reason(decider: Decider, checks: OptionChecks, option: str, consulted: bool, risk_score: float) -> str:
    """Why, in one line (``risk 23.1 % >= gate 6.5 %; default fails leader-brakes; chose slow (passes every
    check)``)."""

    def verdict(k: int) -> str:
        failed = checks.failed_names(0, k)
        return f"fails {', '.join(failed)}" if failed else "passes every check"

    gate = decider.gate.threshold if decider.gate is not None else None
    text = "risk -" if not np.isfinite(risk_score) else f"risk {100 * risk_score:.1f} %"
    if gate is not None:
        text += f" {'>=' if consulted else '<'} gate {100 * gate:.1f} %"
    text += f"; default {verdict(0)}"
    if option == DEFAULT_NAME:
        return text + "; kept default"
    if option not in checks.names:
        return text + "; the model's own numbers"
    return text + f"; chose {option} ({verdict(checks.names.index(option))})"


@dataclass
class LlmProposer:
    """``reflect`` proposer: the ``prompt_style``'s propose prompt, then its refinement with the report
    (``choice``: over ``options``, ``replies`` the answer of each)."""

    advisor: ParamAdvisor
    r_col_m: float
    memories: Sequence[MemoryExample] = ()
    prompt_style: PromptStyle = "paper"
    options: Sequence[OptionLine] = ()
    replies: Mapping[str, PlannerReply] = field(default_factory=dict)
    risk: float = float("nan")  # the choice prompt's risk line (the risk model's score of the scene)

    def __call__(self, ctx: ReflectionContext) -> Proposal:
        desc = describe_scenario(ctx.scenario, ctx.base_goal_xy_m)
        refine = ctx.report is not None and ctx.previous is not None
        adverse = f" Adverse futures: {ctx.adverse.text()}." if ctx.adverse is not None and ctx.adverse.failed else ""
        if self.prompt_style == "choice":
            if not refine or ctx.previous is None or ctx.report is None:
                messages = render_choice_prompt(desc, self.options, risk=self.risk)
            else:
                rejected = str(ctx.previous.meta.get("decision", CUSTOM))
                messages = render_choice_prompt(desc, self.options, risk=self.risk, rejected=rejected,
                                                report=choice_report(ctx.report, ctx.adverse))
            advice = self.advisor.choose(messages, self.replies)
            return _with_decision(proposal_from_advice(advice, messages, self.r_col_m), advice.choice or CUSTOM,
                                  True, float("nan"))
        if self.prompt_style == "compact":
            if not refine or ctx.previous is None or ctx.report is None:
                messages = render_compact_prompt(desc)
            else:
                messages = render_compact_prompt(desc, rejected=_reply_values(ctx.previous),
                                                 report=compact_report(ctx.report) + adverse)
            return proposal_from_advice(self.advisor.advise(messages, variant="fast"), messages, self.r_col_m)
        if not refine or ctx.previous is None or ctx.report is None:
            messages = render_physics_prompt(desc, memories=self.memories)
        else:
            messages = render_physics_prompt(desc, memories=self.memories, previous_reply=ctx.previous.reply or "",
                                             safety_report=ctx.report.to_text(ctx.previous) + adverse)
        return proposal_from_advice(self.advisor.advise(messages, variant="physics"), messages, self.r_col_m)


@dataclass
class MemoryPhase:
    """Runs the memory-collection pipeline on one scenario at a time; its experiences are stored under
    ``config_key`` (the content key of everything that changes its answers)."""

    advisor: ParamAdvisor
    goal_predictor: GoalPredictor
    r_col_m: float
    config_key: str
    thresholds: ReflectionThresholds = field(default_factory=ReflectionThresholds)
    neighbour_mode: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    goal_adjustment: bool = True
    prompt_style: PromptStyle = "paper"
    decider: Decider | None = None  # presets and adverse futures (None: the paper's reflection)

    def run(self, scenario: ScenarioBatch, base_goal_xy_m: np.ndarray | None = None,
            prediction: NeighbourPrediction | None = None) -> ReflectionResult:
        """Reflection loop on a batch of one; ``base_goal_xy_m`` (2,) and ``prediction`` (1, N, F, ...) if the
        caller computed them batched. A ``decider`` adds the adverse futures (and the choice style's presets)."""
        base_goal = (self.goal_predictor.predict_goals(scenario).top[0] if base_goal_xy_m is None
                     else np.asarray(base_goal_xy_m, dtype=np.float64).reshape(2))
        pred = predict_neighbours(scenario, self.neighbour_mode) if prediction is None else prediction
        proposer = LlmProposer(self.advisor, self.r_col_m, prompt_style=self.prompt_style)
        if self.decider is not None and self.prompt_style == "choice":
            checks = self.decider.check(scenario, base_goal[None], pred)
            proposer = replace(proposer, options=option_lines(checks, 0), replies=preset_replies(self.decider.presets),
                               risk=float(self.decider.risk_scores(scenario, checks)[0]))
        return reflect(scenario, proposer, self.thresholds, base_goal_xy_m=base_goal,
                       neighbour_prediction=pred, goal_adjustment=self.goal_adjustment,
                       adverse=self.decider.adverse if self.decider is not None else None)

    def context(self, batch: ScenarioBatch) -> tuple[np.ndarray, NeighbourPrediction]:
        """Goals (B, 2) and predicted neighbours of ``batch``, batched (what ``run`` takes per scenario)."""
        return self.goal_predictor.predict_goals(batch).top, predict_neighbours(batch, self.neighbour_mode)

    def experience(self, scenario: ScenarioBatch, result: ReflectionResult, scenario_digest: str) -> Experience:
        return Experience.from_reflection(result, scenario, scenario_digest=scenario_digest,
                                          config_key=self.config_key, model=self.advisor.backend.spec)


@dataclass(frozen=True)
class CollectStats:
    """Counts of one collection run: ``fallback_results`` (scenarios), ``fallback_replies`` (all iterations),
    ``cached_calls`` of ``calls``; ``run``: throughput, latency and request counters."""

    total: int
    skipped: int
    stored: int
    validated: int
    fallback_results: int
    fallback_replies: int
    refinements: int
    calls: int
    cached_calls: int
    seconds: float
    run: RunStats | None = None


def collect(phase: MemoryPhase, batch: ScenarioBatch, bank: MemoryBank,
            progress: Callable[[RunStatus], None] | None = None, *, runner: RunnerConfig | None = None) -> CollectStats:
    """The memory collection phase over ``batch``, resumable (scenarios with a real result are skipped), committed
    in scenario order whatever ``runner.concurrency``. A scenario whose requests failed in transport is not stored
    (``ScenariosFailedError`` at the end); an unreachable server or too many failures stop the run
    (``BackendUnavailableError``, ``RunStoppedError``)."""
    t0 = time.perf_counter()
    key = phase.config_key
    digests = scenario_digests(batch)
    done = bank.done_digests(key)
    todo = [i for i in range(len(batch)) if digests[i] not in done]
    counts = {"stored": 0, "validated": 0, "fallback_results": 0, "fallback_replies": 0, "refinements": 0,
              "calls": 0, "cached": 0}

    # goals and predicted neighbours batched per fixed block of scenarios (the reflection rounds are per scenario)
    contexts: BlockCache[tuple[np.ndarray, NeighbourPrediction]] = BlockCache(
        CONTEXT_BLOCK, len(batch), lambda rows: phase.context(batch.take(rows)))

    def work(i: int) -> tuple[ScenarioBatch, ReflectionResult]:
        one = batch.take([i])
        (goals, pred), k, _ = contexts.get(i)
        return one, phase.run(one, goals[k], pred.take(slice(k, k + 1)))

    def write(i: int, done_: tuple[ScenarioBatch, ReflectionResult]) -> None:
        one, result = done_
        exp = phase.experience(one, result, str(digests[i]))
        counts["stored"] += int(bank.add(exp))
        counts["validated"] += int(exp.validated)
        counts["fallback_results"] += int(exp.fallback)
        counts["fallback_replies"] += sum(int(it.proposal.fallback) for it in result.iterations)
        counts["refinements"] += result.n_refinements
        for it in result.iterations:
            counts["calls"] += int(it.proposal.meta.get("attempts", 0))
            counts["cached"] += int(it.proposal.meta.get("cached_attempts", 0))
        contexts.discard_below(i + 1)

    run = run_ordered(todo, work, write, config=runner, advisor=phase.advisor,
                      is_fallback=lambda d: bool(d[1].final.proposal.fallback), progress=progress)
    return CollectStats(len(batch), len(batch) - len(todo), counts["stored"], counts["validated"],
                        counts["fallback_results"], counts["fallback_replies"], counts["refinements"],
                        counts["calls"], counts["cached"], time.perf_counter() - t0, run)


def _summary_of_features(features: Sequence[float]) -> str:
    f = dict(zip(FEATURE_NAMES, features, strict=True))
    return (
        f"{int(f['n_vehicles'])} vehicles near, ego {f['ego_speed_mps']:.1f} m/s, "
        f"{'changing lane' if f['lane_change'] > 0.5 else 'keeping lane'}, nearest {f['min_dist_m']:.1f} m, "
        f"mean distance {f['mean_dist_m']:.1f} m, neighbours {f['mean_nbr_speed_mps']:.1f} m/s"
    )


def _outcome(metrics: dict[str, object]) -> str:
    def num(key: str) -> str:
        v = metrics.get(key)
        try:
            x = float(v)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            return "n/a"
        return "none" if not np.isfinite(x) else f"{x:.1f}"

    return f"min TTC {num('min_ttc_s')} s, min in-path gap {num('min_path_gap_m')} m"


def memory_example(exp: Experience) -> MemoryExample:
    """A stored experience as a few-shot example for the fast prompt."""
    values = {k: v for k, v in exp.params.as_dict().items() if k in LLM_PARAM_RANGES}
    reply = PlannerReply(**values, lon_factor=exp.lon_factor, lane_factor=exp.lane_factor, rationale=exp.rationale)
    return MemoryExample(summary=_summary_of_features(exp.features), reply=reply, outcome=_outcome(exp.metrics_after))


@dataclass
class Retriever:
    """Top-k validated memories by the (fixed) §III-E similarity; thread-safe. ``config_key``: only this collection
    configuration's (None: any); ``allowed_ids``: only these row ids. ``allow_same_vehicle`` False leaves out the
    query's own vehicle and windows overlapping it in the same recording (their history is the query's future)."""

    bank: MemoryBank
    k: int = TOP_K
    config_key: str | None = None
    allowed_ids: np.ndarray | None = None
    allow_same_vehicle: bool = False
    _lock: threading.Lock = field(default_factory=threading.Lock, init=False, repr=False, compare=False)

    def candidates(self, scenario: ScenarioBatch) -> MemoryFeatures:
        """The memories this query may retrieve (before ranking)."""
        with self._lock:
            mem = self.bank.features_matrix(validated_only=True, config_key=self.config_key)
        if self.allowed_ids is not None:
            mem = mem.take(np.isin(mem.ids, self.allowed_ids))
        if not self.allow_same_vehicle and len(mem):
            same_recording = mem.recording_key == scenario.recording_key[0]
            same_vehicle = same_recording & (mem.ego_id == int(scenario.ego_id[0]))
            overlapping = same_recording & (np.abs(mem.frame0 - int(scenario.frame0[0])) < N_TOTAL)
            mem = mem.take(~(same_vehicle | overlapping))
        return mem

    def retrieve(self, scenario: ScenarioBatch) -> list[tuple[Experience, float]]:
        mem = self.candidates(scenario)
        if len(mem) == 0 or self.k == 0:
            return []
        idx, sims = top_k(scenario_features(scenario), mem.features, min(self.k, len(mem)))
        with self._lock:
            exps = self.bank.get([int(mem.ids[j]) for j in idx[0]])
        return list(zip(exps, [float(s) for s in sims[0]], strict=True))


@dataclass(frozen=True)
class Assessment:
    """What the decision step knows of one scenario before anyone chooses: the scene as the prompt
    describes it, every preset's checks (a batch of one), the risk score and whether the gate consults."""

    scenario: ScenarioBatch
    description: ScenarioDescription
    checks: OptionChecks
    risk_score: float
    consulted: bool

    def choice_messages(self) -> list[Message]:
        return render_choice_prompt(self.description, option_lines(self.checks, 0), risk=self.risk_score)


@dataclass
class FastPhase:
    """Fast inference: retrieval + fast prompt + one call of the fast model. ``chooser`` (with a ``decider``): where
    the gate fires, it picks the preset instead of the model (``advisor`` may then be None)."""

    advisor: ParamAdvisor | None
    goal_predictor: GoalPredictor
    r_col_m: float
    retriever: Retriever | None
    static_examples: Sequence[MemoryExample] = ()  # the "FS" ablation: fixed examples, no retrieval
    variant: Variant = "fast"
    prompt_style: PromptStyle = "paper"
    decider: Decider | None = None  # presets, their checks and the risk gate (None: always the model, no presets)
    chooser: Chooser | None = None

    def __post_init__(self) -> None:
        if self.chooser is not None and self.decider is None:
            raise ValueError("a chooser picks among the decision step's presets: it needs the decision step")
        if self.advisor is None and self.chooser is None:
            raise ValueError("the fast phase needs a model (advisor) or a chooser")

    def propose(self, scenario: ScenarioBatch, base_goal_xy_m: np.ndarray) -> tuple[Proposal, list[tuple[str, float]]]:
        """One LLM call for a batch of one: the proposal and the retrieved memories (scenario id, similarity)."""
        proposal, retrieved = self.propose_retrieved(scenario, base_goal_xy_m)
        return proposal, [(e.scenario_id, s) for e, s in retrieved]

    def assess(self, scenario: ScenarioBatch, base_goal_xy_m: np.ndarray,
               prediction: NeighbourPrediction | None = None) -> Assessment:
        """Scenario (a batch of one) checked and scored by the decision step (``prediction``: its predicted
        neighbours, default IDM)."""
        if self.decider is None:
            raise ValueError("assess needs the decision step")
        pred = prediction if prediction is not None else predict_neighbours(scenario, NeighbourPredictionMode.IDM)
        checks = self.decider.check(scenario, np.asarray(base_goal_xy_m, dtype=np.float64).reshape(1, 2), pred)
        risk = self.decider.risk_scores(scenario, checks)
        return Assessment(scenario, describe_scenario(scenario, base_goal_xy_m), checks, float(risk[0]),
                          bool(self.decider.consulted(risk)[0]))

    def propose_retrieved(self, scenario: ScenarioBatch, base_goal_xy_m: np.ndarray,
                          prediction: NeighbourPrediction | None = None, *, prompt_of: Assessment | None = None,
                          ) -> tuple[Proposal, list[tuple[Experience, float]]]:
        """``propose`` returning the retrieved experiences. With a ``decider``, below the gate the defaults are kept
        without a call; where it fires the ``chooser`` or the model picks a preset (``decide``; ``prompt_of``: the
        shuffled-scene control). ``Proposal.meta`` records ``decision``, ``consulted``, ``risk_score``."""
        retrieved = self.retrieve(scenario)
        if self.decider is None:
            return self._ask(scenario, base_goal_xy_m, retrieved), retrieved
        return self.decide(self.assess(scenario, base_goal_xy_m, prediction), base_goal_xy_m, retrieved,
                           prompt_of=prompt_of), retrieved

    def retrieve(self, scenario: ScenarioBatch) -> list[tuple[Experience, float]]:
        """The memories retrieved for a scenario (none without a retriever)."""
        return self.retriever.retrieve(scenario) if self.retriever is not None else []

    def preset_proposal(self, option: str, rationale: str) -> Proposal:
        """A preset of the decision step as a proposal that made no model call."""
        if self.decider is None:
            raise ValueError("presets belong to the decision step")
        reply = preset_replies(self.decider.presets)[option]
        return Proposal(params=SocialForceParams(**reply.params(), r_col_m=self.r_col_m), lon_factor=reply.lon_factor,
                        lane_factor=reply.lane_factor, rationale=rationale)

    def decide(self, a: Assessment, base_goal_xy_m: np.ndarray, retrieved: Sequence[tuple[Experience, float]] = (),
               *, prompt_of: Assessment | None = None) -> Proposal:
        """The decision for an assessed scenario (``propose_retrieved``)."""
        decider = self.decider
        assert decider is not None
        checks, risk_score = a.checks, a.risk_score
        if not a.consulted:
            kept = self.preset_proposal(
                DEFAULT_NAME, f"risk {risk_score:.3f} below the gate's threshold: the defaults, no model call")
            return _with_decision(kept, DEFAULT_NAME, False, risk_score,
                                  decision_reason(decider, checks, DEFAULT_NAME, False, risk_score))
        if self.chooser is not None:
            option = checks.names[int(self.chooser.choose(a.scenario, checks, np.array([risk_score]))[0])]
            proposal = self.preset_proposal(option, f"the chooser picked {option}")
        elif self.prompt_style == "choice":
            assert self.advisor is not None
            messages = (prompt_of if prompt_of is not None else a).choice_messages()
            advice = self.advisor.choose(messages, preset_replies(decider.presets))
            proposal = proposal_from_advice(advice, messages, self.r_col_m)
            option = advice.choice or CUSTOM
        else:
            return _with_decision(self._ask(a.scenario, base_goal_xy_m, retrieved), CUSTOM, True, risk_score,
                                  decision_reason(decider, checks, CUSTOM, True, risk_score))
        reason = decision_reason(decider, checks, option, True, risk_score)
        if prompt_of is not None:
            reason += f"; answered the prompt of {prompt_of.scenario.scenario_id[0]}"
        final = decider.verified(checks, option) if decider.verify else option
        if final != option:  # the physics overrules the choice: another preset fails fewer checks
            reply = preset_replies(decider.presets)[final]
            proposal = replace(proposal, params=SocialForceParams(**reply.params(), r_col_m=self.r_col_m),
                               lon_factor=reply.lon_factor, lane_factor=reply.lane_factor,
                               rationale=f"the {'model' if self.chooser is None else 'chooser'} chose {option}; "
                                         f"{final} fails fewer checks")
            failed = checks.failed_names(0, checks.names.index(final))
            reason += (f"; verified: {final} fails fewer checks "
                       f"({'fails ' + ', '.join(failed) if failed else 'passes every check'})")
        return _with_decision(proposal, final, True, risk_score, reason)

    def _ask(self, scenario: ScenarioBatch, base_goal_xy_m: np.ndarray,
             retrieved: Sequence[tuple[Experience, float]]) -> Proposal:
        """One call for the model's own eight numbers (paper or compact prompt)."""
        assert self.advisor is not None
        desc = describe_scenario(scenario, base_goal_xy_m)
        if self.prompt_style == "compact":  # the fine-tuned model: no few-shot examples in its prompt
            messages = render_compact_prompt(desc)
        else:
            examples = [memory_example(e) for e, _ in retrieved] or list(self.static_examples)
            messages = render_fast_prompt(desc, memories=examples)
        return proposal_from_advice(self.advisor.advise(messages, variant=self.variant), messages, self.r_col_m)
