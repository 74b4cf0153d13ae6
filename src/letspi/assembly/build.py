"""Configurations -> shared objects: goal predictors, LLM advisors, LetsPi phases. ``Builder`` loads one model per
LLM configuration and one goal predictor per goal configuration, at build time (``BuiltPlanner.load_s``)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from letspi.learned.goal_model import LearnedGoalPredictor
from letspi.llm.cache import ResponseCache
from letspi.llm.client import ParamAdvisor, RetryPolicy
from letspi.llm.config import LlmConfig
from letspi.llm.schema import fallback_reply_from_params
from letspi.llm.spec import make_backend
from letspi.llm.types import LoadingBackend
from letspi.method.config import MemoryPhaseConfig
from letspi.method.memory import MemoryBank
from letspi.method.phases import FastPhase, MemoryPhase, Retriever, memory_example
from letspi.method.thresholds import ReflectionThresholds
from letspi.physics.goals import GoalPredictor, KinematicGoalPredictor, OracleGoalPredictor
from letspi.physics.mobil import MobilGoalPredictor
from letspi.planners.config import GoalsConfig, SfParamsConfig
from letspi.planners.llm import FastPlannerConfig


class ConfigurationChangedError(ValueError):
    """What a configuration pins (a memory snapshot) no longer matches what is on disk."""


@dataclass
class Builder:
    """Builds planners and phases from configurations, sharing models. ``cache``: the LLM response cache
    (``"default"``: ``ResponseCache()`` when a configuration asks for it; ``None``: never)."""

    cache: ResponseCache | str | None = "default"
    _advisors: dict[tuple[str, str, bool], tuple[ParamAdvisor, float]] = field(default_factory=dict)
    _goals: dict[str, GoalPredictor] = field(default_factory=dict)
    _default_cache: ResponseCache | None = None

    # shared parts ------------------------------------------------------------------------------
    def goal_predictor(self, goals: GoalsConfig) -> GoalPredictor:
        key = goals.key()
        if key not in self._goals:
            if goals.source == "learned":
                assert goals.weights_dir is not None
                self._goals[key] = LearnedGoalPredictor.from_dir(goals.weights_dir)
            elif goals.source == "oracle":
                self._goals[key] = OracleGoalPredictor()
            elif goals.source == "mobil":
                self._goals[key] = MobilGoalPredictor()
            else:
                self._goals[key] = KinematicGoalPredictor()
        return self._goals[key]

    def _response_cache(self, llm: LlmConfig) -> ResponseCache | None:
        if not llm.cache or self.cache is None:
            return None
        if isinstance(self.cache, ResponseCache):
            return self.cache
        if self._default_cache is None:
            self._default_cache = ResponseCache()
        return self._default_cache

    def advisor_with_load_time(self, llm: LlmConfig, fallback: SfParamsConfig) -> tuple[ParamAdvisor, float]:
        """The advisor for ``llm`` (fallback reply: ``fallback``'s parameters) and its model's load time [s] (0 after
        the first)."""
        # the cache switch is left out of the key (it cannot change an answer) but not out of this one:
        # a configuration that asks for no cache must not get an advisor built with one
        key = (llm.key(), fallback.key(), llm.cache)
        if key in self._advisors:
            return self._advisors[key][0], 0.0
        t0 = time.perf_counter()
        options = {"lora_path": llm.adapter_path} if llm.adapter_path is not None else {}
        backend = make_backend(llm.spec, **options)
        if isinstance(backend, LoadingBackend):
            backend.load()
        advisor = ParamAdvisor(
            backend, cache=self._response_cache(llm),
            retry=RetryPolicy(max_attempts=llm.max_attempts, timeout_s=llm.timeout_s),
            settings=llm.decoding(), use_schema=llm.use_schema,
            fallback_reply=fallback_reply_from_params(fallback.params()),
        )
        load_s = time.perf_counter() - t0
        self._advisors[key] = (advisor, load_s)
        return advisor, load_s

    def memory_phase(self, config: MemoryPhaseConfig) -> tuple[MemoryPhase, float]:
        """The memory-collection phase (its experiences are stored under ``config.key()``) and model load time."""
        advisor, load_s = self.advisor_with_load_time(config.llm, config.sf_params)
        decider = (config.decision.decider(config.sf_params.params(), config.reflection)
                   if config.decision is not None else None)
        phase = MemoryPhase(advisor, self.goal_predictor(config.goals), float(config.sf_params.values["r_col_m"]),
                            config_key=config.key(), thresholds=config.reflection, neighbour_mode=config.neighbours,
                            goal_adjustment=config.goal_adjustment, prompt_style=config.llm.prompt_style,
                            decider=decider)
        return phase, load_s

    def fast_phase(self, config: FastPlannerConfig) -> tuple[FastPhase, float]:
        """The fast-inference phase of ``letspi-fast`` (retrieval) or ``letspi-fs`` (three static examples)
        over the memory snapshot ``config`` pins, and model load time."""
        advisor, load_s = (self.advisor_with_load_time(config.llm, config.sf_params) if config.llm is not None
                           else (None, 0.0))
        ref = config.memory
        bank = MemoryBank.open(ref.path, readonly=True)
        ids, sha = bank.snapshot(ref.collection_key)
        if sha != ref.snapshot_sha256:
            bank.close()
            raise ConfigurationChangedError(
                f"{ref.path}: the memory bank changed since this configuration was made ({ref.n_memories} -> "
                f"{len(ids)} retrievable memories); resolve the configuration again")
        if ref.subset_fraction is not None:
            ids = bank.sample_fraction(ref.subset_fraction, seed=ref.subset_seed,
                                       config_key=ref.collection_key).ids
        goals = self.goal_predictor(config.goals)
        r_col = float(config.sf_params.values["r_col_m"])
        decider = (config.decision.decider(config.sf_params.params(), ReflectionThresholds())
                   if config.decision is not None else None)
        if config.kind == "letspi-fast":
            retriever = Retriever(bank, k=config.top_k, config_key=ref.collection_key, allowed_ids=ids,
                                  allow_same_vehicle=ref.allow_same_vehicle)
            chooser = config.chooser.chooser() if config.chooser is not None else None
            return FastPhase(advisor, goals, r_col, retriever,
                             prompt_style=config.llm.prompt_style if config.llm is not None else "choice",
                             decider=decider, chooser=chooser), load_s
        assert config.llm is not None  # letspi-fs always has its model
        # letspi-fs: three static examples (the first three memories of the snapshot), no retrieval; the decision
        # step as letspi-fast's (the choice prompt carries no examples: FS then differs by the shield's memories)
        static = [memory_example(e) for e in bank.get(np.sort(ids)[:3])]
        return FastPhase(advisor, goals, r_col, None, static_examples=static,
                         prompt_style=config.llm.prompt_style, decider=decider), load_s
