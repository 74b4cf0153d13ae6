"""Requests -> configurations: read every file and environment variable once, fingerprint them.

``PlannerOptions`` is what a user asks for (CLI flags: a model spec, a goal source, a parameter
file, ...). ``Resolver`` turns it into frozen configurations (``letspi.planners.config``; each kind's
resolution is its entry in ``letspi.assembly.planner_table``), whose content keys identify
results: the parameter *values* instead of a file name, the SHA-256 of the weights a goal source or
an embedded model uses, the text of the prompts, a snapshot of the memory bank. Environment
variables that change answers (``$LETSPI_GOAL_WEIGHTS``, ``$LETSPI_GNP_WEIGHTS``) are read here and
nowhere else, so they always show up in a configuration.
"""

from __future__ import annotations

import functools
import hashlib
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from letspi.assembly.planner_table import planner_kind
from letspi.learned.weights import MANIFEST_FILE, WEIGHTS_FILE, WeightsError, load_weights, shipped_weights_dir
from letspi.llm.backends.llamacpp import LlamaRuntime
from letspi.llm.client import RetryPolicy
from letspi.llm.compact import PROMPT_STYLES
from letspi.llm.fingerprint import prompt_fingerprint
from letspi.llm.models import adapter_prompt_style, is_fine_tuned, locate_adapter, locate_model
from letspi.llm.spec import parse_spec
from letspi.method.decide import recommended_threshold
from letspi.method.matching import TOP_K
from letspi.method.memory import MemoryBank
from letspi.method.prompt_samples import prompt_text_samples
from letspi.method.thresholds import MAX_ITERATIONS, ReflectionThresholds
from letspi.physics.neighbours import NeighbourPredictionMode
from letspi.planners.config import (
    DecisionConfig,
    GoalsConfig,
    LlmConfig,
    MemoryPhaseConfig,
    MemoryRef,
    PlannerConfig,
    SfParamsConfig,
    WeightsConfig,
)
from letspi.planners.sf_params import load_sf_params

GOAL_WEIGHTS_ENV = "LETSPI_GOAL_WEIGHTS"
GNP_WEIGHTS_ENV = "LETSPI_GNP_WEIGHTS"
MLP_WEIGHTS_ENV = "LETSPI_MLP_WEIGHTS"
DEFAULT_LLM = "llamacpp:smollm2-135m-letspi"
DEFAULT_FAST_LLM = "llamacpp:smollm2-135m-letspi"
GOAL_SOURCES: tuple[str, ...] = ("learned", "kinematic", "oracle")


@dataclass(frozen=True)
class PlannerOptions:
    """What the user asks for (CLI flags map onto these); ``Resolver`` makes configurations of it."""

    sf_params_file: Path | None = None
    neighbour_mode: str = "idm"
    goals: str = "learned"  # learned (shipped transformer or $LETSPI_GOAL_WEIGHTS), kinematic, oracle
    llm: str = DEFAULT_LLM  # memory-collection / single-shot model spec
    fast_llm: str = DEFAULT_FAST_LLM  # fast-inference model spec
    memory: Path | None = None  # memory bank (SQLite) for letspi-fast / letspi-fs
    memory_key: str | None = None  # only memories collected under this configuration key (None: all)
    top_k: int = TOP_K
    max_iterations: int = MAX_ITERATIONS  # reflection refinements of letspi-memory (0 = "w/o reflection")
    goal_adjustment: bool = True  # False = "w/o goal adjustment" ablation
    llm_cache: bool = True  # persistent response cache
    llm_timeout_s: float = RetryPolicy.timeout_s  # per-request timeout (cosmetic: not part of any key)
    allow_same_vehicle: bool = False  # retrieval may return the query's own vehicle (a leak; labelled)
    memory_fraction: float | None = None  # memory-size ablation: a reproducible subset
    memory_seed: int = 0
    shield: bool = True  # the LLM planners' safety shield (False: the paper-faithful ablation)
    mlp_weights: Path | None = None  # the mlp regressor (default: $LETSPI_MLP_WEIGHTS)
    prompt_style: str | None = None  # paper | compact | choice; None: what the fine-tuned adapter was trained on
    decide: bool | None = None  # LetsPi's decision step (presets, adverse futures, gate); None: on for the choice style
    presets_file: Path | None = None  # the decision step's presets (default: the shipped ones)
    adverse: bool = True  # check against the adverse futures (False: the prediction only)
    gate: bool = True  # the risk gate of the fast phase (False: the model is asked on every scenario)
    gate_threshold: float | None = None  # None: the risk model's recommended threshold
    risk_model_file: Path | None = None  # the gate's model (default: the shipped one)
    frenet_weights_file: Path | None = None  # frenet cost weights (default: the shipped fit)


def sha256_files(paths: list[Path]) -> str:
    """SHA-256 over the names and bytes of ``paths`` (in the given order)."""
    h = hashlib.sha256()
    for p in paths:
        h.update(p.name.encode())
        with open(p, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


@functools.lru_cache(maxsize=16)
def _file_sha256(path: str, size: int, mtime_ns: int) -> str:
    return sha256_files([Path(path)])


def file_sha256(path: Path) -> str:
    """SHA-256 of one file, computed once per process for an unchanged file (size, mtime)."""
    st = Path(path).stat()
    return _file_sha256(str(Path(path).resolve()), st.st_size, st.st_mtime_ns)


def weights_sha256(model_dir: Path) -> str:
    """Fingerprint of a trained model directory (``weights.npz`` and ``manifest.json``)."""
    return sha256_files([Path(model_dir) / WEIGHTS_FILE, Path(model_dir) / MANIFEST_FILE])


def prompt_sha256() -> str:
    """Fingerprint of the prompt text as rendered (``letspi.llm.fingerprint``, ``letspi.method.prompt_samples``)."""
    return prompt_fingerprint(prompt_text_samples())


class Resolver:
    """Turns ``PlannerOptions`` into configurations (see the module docstring).

    ``env`` defaults to ``os.environ``; tests pass a dict. Fingerprints are computed once per resolver.
    """

    def __init__(self, options: PlannerOptions | None = None, env: Mapping[str, str] | None = None) -> None:
        self.options = options or PlannerOptions()
        self.env = os.environ if env is None else env

    # building blocks ---------------------------------------------------------------------------
    @functools.cached_property
    def sf_params(self) -> SfParamsConfig:
        params, _ = load_sf_params(self.options.sf_params_file)
        source = "shipped" if self.options.sf_params_file is None else str(self.options.sf_params_file)
        return SfParamsConfig.of(params, source)

    @functools.cached_property
    def neighbours(self) -> NeighbourPredictionMode:
        try:
            return NeighbourPredictionMode(self.options.neighbour_mode)
        except ValueError:
            valid = ", ".join(m.value for m in NeighbourPredictionMode)
            raise ValueError(
                f"unknown neighbour prediction {self.options.neighbour_mode!r}; available: {valid}") from None

    @functools.cached_property
    def goals(self) -> GoalsConfig:
        source = self.options.goals
        if source not in GOAL_SOURCES:
            raise ValueError(f"unknown goal source {source!r}; available: {', '.join(GOAL_SOURCES)}")
        if source != "learned":
            return GoalsConfig(source=source)  # type: ignore[arg-type]
        requested = self.env.get(GOAL_WEIGHTS_ENV)
        chosen = Path(requested) if requested else shipped_weights_dir("goal")
        try:
            load_weights(chosen, expected_model="goal")
        except (WeightsError, OSError) as exc:
            if requested:  # an explicit request that does not load is an error, never a silent swap
                raise WeightsError(f"${GOAL_WEIGHTS_ENV}={requested}: {exc}") from exc
            return GoalsConfig(source="kinematic", fallback_reason=f"no usable shipped goal weights ({exc})")
        return GoalsConfig(source="learned", weights_sha256=weights_sha256(chosen), weights_dir=str(chosen))

    @functools.cached_property
    def gnp_weights(self) -> WeightsConfig:
        requested = self.env.get(GNP_WEIGHTS_ENV)
        chosen = Path(requested) if requested else shipped_weights_dir("gnp")
        load_weights(chosen, expected_model="gnp")  # WeightsError names the directory
        return WeightsConfig(weights_sha256=weights_sha256(chosen), weights_dir=str(chosen))

    @functools.cached_property
    def mlp_weights(self) -> WeightsConfig:
        """The ``mlp`` regressor: ``--mlp-weights`` or ``$LETSPI_MLP_WEIGHTS`` (nothing is shipped)."""
        requested = self.options.mlp_weights or self.env.get(MLP_WEIGHTS_ENV)
        if not requested:
            raise ValueError(f"the mlp planner needs trained weights: --mlp-weights DIR or ${MLP_WEIGHTS_ENV} "
                             "(train them with `letspi train mlp`)")
        chosen = Path(requested)
        load_weights(chosen, expected_model="param-mlp")  # WeightsError names the directory
        return WeightsConfig(weights_sha256=weights_sha256(chosen), weights_dir=str(chosen))

    def llm(self, spec: str) -> LlmConfig:
        """The model ``spec`` with its weights fingerprint (local files only) and the prompt fingerprint."""
        parsed = parse_spec(spec)
        model_sha = model_path = adapter_sha = adapter_path = runtime = None
        if parsed.kind == "llamacpp":
            runtime = LlamaRuntime.from_env(dict(self.env)).identity()
            path = locate_model(parsed.model)
            model_sha, model_path = file_sha256(path), str(path)
            adapter = locate_adapter(parsed.model, self.env)  # $LETSPI_LLM_ADAPTER or the shipped one
            if adapter is not None:
                adapter_sha, adapter_path = file_sha256(adapter), str(adapter)
        style = self.options.prompt_style
        if style is None:  # what the adapter was trained on (compact for an adapter that does not say)
            trained = adapter_prompt_style(Path(adapter_path)) if adapter_path is not None else None
            style = (trained or "compact") if parsed.kind == "llamacpp" and is_fine_tuned(parsed.model) else "paper"
        if style not in PROMPT_STYLES:
            raise ValueError(f"unknown prompt style {style!r}; available: {', '.join(PROMPT_STYLES)}")
        return LlmConfig(spec=str(parsed), model_sha256=model_sha, model_path=model_path,
                         adapter_sha256=adapter_sha, adapter_path=adapter_path, runtime=runtime,
                         prompt_style=style,  # type: ignore[arg-type]
                         prompt_sha256=self._prompt_sha, cache=self.options.llm_cache,
                         timeout_s=self.options.llm_timeout_s)

    @functools.cached_property
    def _prompt_sha(self) -> str:
        return prompt_sha256()

    def decision(self, prompt_style: str, *, gate: bool = True, always: bool = False) -> DecisionConfig | None:
        """The decision step (``--decide``; default: on for the choice style, or ``always``); the gate only
        where ``gate`` (the fast phase and ``sf-check``) and ``--gate`` allow it."""
        o = self.options
        on = o.decide if o.decide is not None else (always or prompt_style == "choice")
        if prompt_style == "choice" and not on:
            raise ValueError("the choice prompt style needs the decision step's presets (drop --no-decide)")
        if not on:
            return None
        threshold = None
        if gate and o.gate:
            threshold = o.gate_threshold if o.gate_threshold is not None else recommended_threshold(o.risk_model_file)
        return DecisionConfig.resolve(o.presets_file, o.adverse, threshold, o.risk_model_file)

    def memory_phase(self, *, spec: str | None = None, max_iterations: int | None = None,
                     goal_adjustment: bool | None = None) -> MemoryPhaseConfig:
        """The collection configuration (defaults from the options)."""
        iterations = self.options.max_iterations if max_iterations is None else max_iterations
        llm = self.llm(spec or self.options.llm)
        return MemoryPhaseConfig(
            llm=llm, goals=self.goals, neighbours=self.neighbours,
            sf_params=self.sf_params, reflection=ReflectionThresholds(max_iterations=iterations),
            goal_adjustment=self.options.goal_adjustment if goal_adjustment is None else goal_adjustment,
            decision=self.decision(llm.prompt_style, gate=False),
        )

    def memory_ref(self) -> MemoryRef:
        """A snapshot of the memories ``--memory`` (restricted to ``--memory-key``) offers now."""
        path = self.options.memory
        if path is None:
            raise ValueError("letspi-fast and letspi-fs need a memory bank: --memory FILE "
                             "(build one with `letspi collect`)")
        if not Path(path).exists():
            raise FileNotFoundError(f"{path}: no memory bank (build one with `letspi collect`)")
        with MemoryBank.open(path, readonly=True) as bank:
            ids, sha = bank.snapshot(self.options.memory_key)
        return MemoryRef(path=str(path), collection_key=self.options.memory_key, snapshot_sha256=sha,
                         n_memories=len(ids), allow_same_vehicle=self.options.allow_same_vehicle,
                         subset_fraction=self.options.memory_fraction, subset_seed=self.options.memory_seed)

    # planners ------------------------------------------------------------------------------------
    def planner(self, kind: str) -> PlannerConfig:
        """The configuration of planner ``kind`` (``ValueError`` listing the kinds for an unknown one)."""
        config: PlannerConfig = planner_kind(kind).resolve(self)
        return config
