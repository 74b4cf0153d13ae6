"""Requests -> configurations: every file and environment variable that changes answers is read here only, once, and
fingerprinted (parameter values, weights' SHA-256, prompt text, a memory snapshot) into a configuration."""

from __future__ import annotations

import functools
import hashlib
import os
from collections.abc import Mapping
from pathlib import Path

from letspi.learned.weights import MANIFEST_FILE, WEIGHTS_FILE, WeightsError, load_weights, shipped_weights_dir
from letspi.llm.backends.llamacpp import LlamaRuntime
from letspi.llm.backends.llamacpp_open import runnable_model
from letspi.llm.compact import PROMPT_STYLES
from letspi.llm.config import LlmConfig
from letspi.llm.fingerprint import prompt_fingerprint
from letspi.llm.models import adapter_prompt_style, is_fine_tuned, locate_adapter
from letspi.llm.spec import backend_kind, installed_origin, parse_spec
from letspi.method.config import DecisionConfig, MemoryPhaseConfig, MemoryRef
from letspi.method.decide import recommended_threshold
from letspi.method.memory import MemoryBank
from letspi.method.prompt_samples import prompt_text_samples
from letspi.method.thresholds import ReflectionThresholds
from letspi.physics.neighbours import NeighbourPredictionMode
from letspi.planners.config import (
    GOAL_SOURCES,
    GOAL_WEIGHTS,
    GOAL_WEIGHTS_ENV,
    GOALS,
    NEIGHBOURS,
    SF_PARAMS,
    GoalsConfig,
    SfParamsConfig,
    WeightsConfig,
)
from letspi.planners.decision import (
    ADVERSE,
    DECIDE,
    GATE,
    GATE_THRESHOLD,
    IDM_FALLBACK,
    KEEP_LANE,
    PRESETS,
    RISK_MODEL,
    VERIFY,
)
from letspi.planners.gnp import GNP_WEIGHTS, GNP_WEIGHTS_ENV
from letspi.planners.llm import (
    ALLOW_SAME_VEHICLE,
    GOAL_ADJUSTMENT,
    LLM,
    LLM_CACHE,
    LLM_TIMEOUT,
    MAX_REFINEMENTS,
    MEMORY,
    MEMORY_FRACTION,
    MEMORY_KEY,
    MEMORY_SEED,
    PROMPT_STYLE,
)
from letspi.planners.mlp import MLP_WEIGHTS, MLP_WEIGHTS_ENV
from letspi.planners.options import DEFAULT_OPTIONS, PlannerOptions
from letspi.planners.sf_params import load_sf_params
from letspi.suggest import unknown


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


def path_sha256(path: Path) -> str:
    """SHA-256 of a weights file, or of every file under a weights directory (by relative path)."""
    path = Path(path)
    if not path.is_dir():
        return file_sha256(path)
    files = sorted(p for p in path.rglob("*") if p.is_file())
    h = hashlib.sha256()
    for p in files:
        h.update(p.relative_to(path).as_posix().encode())
        h.update(file_sha256(p).encode())
    return h.hexdigest()


def weights_sha256(model_dir: Path) -> str:
    """Fingerprint of a trained model directory (``weights.npz`` and ``manifest.json``)."""
    return sha256_files([Path(model_dir) / WEIGHTS_FILE, Path(model_dir) / MANIFEST_FILE])


def prompt_sha256() -> str:
    """Fingerprint of the prompt text as rendered (``letspi.llm.fingerprint``, ``letspi.method.prompt_samples``)."""
    return prompt_fingerprint(prompt_text_samples())


def goals_config(source: str, weights: Path | None = None, env: Mapping[str, str] | None = None) -> GoalsConfig:
    """The goal source ``source`` (``learned``: ``weights``, else ``$LETSPI_GOAL_WEIGHTS``, else the shipped ones,
    fingerprinted; without usable shipped weights ``kinematic``, saying why)."""
    if source not in GOAL_SOURCES:
        raise ValueError(unknown("goal source", source, GOAL_SOURCES))
    if source != "learned":
        return GoalsConfig(source=source)  # type: ignore[arg-type]
    env = os.environ if env is None else env
    requested = str(weights) if weights is not None else env.get(GOAL_WEIGHTS_ENV)
    chosen = Path(requested) if requested else shipped_weights_dir("goal")
    try:
        load_weights(chosen, expected_model="goal")
    except (WeightsError, OSError) as exc:
        if requested:  # an explicit request that does not load is an error, never a silent swap
            origin = f"--goal-weights {weights}" if weights is not None else f"${GOAL_WEIGHTS_ENV}={requested}"
            raise WeightsError(f"{origin}: {exc}") from exc
        return GoalsConfig(source="kinematic", fallback_reason=f"no usable shipped goal weights ({exc})")
    return GoalsConfig(source="learned", weights_sha256=weights_sha256(chosen), weights_dir=str(chosen))


class Resolver:
    """``PlannerOptions`` -> configuration parts, fingerprinted once per resolver; ``env`` default ``os.environ``."""

    def __init__(self, options: PlannerOptions | None = None, env: Mapping[str, str] | None = None) -> None:
        self.options = options or DEFAULT_OPTIONS
        self.env = os.environ if env is None else env

    # building blocks ---------------------------------------------------------------------------
    @functools.cached_property
    def sf_params(self) -> SfParamsConfig:
        path = self.options.get(SF_PARAMS)
        params, _ = load_sf_params(path)
        return SfParamsConfig.of(params, "shipped" if path is None else str(path))

    @functools.cached_property
    def neighbours(self) -> NeighbourPredictionMode:
        mode = self.options.get(NEIGHBOURS)
        try:
            return NeighbourPredictionMode(mode)
        except ValueError:
            modes = [m.value for m in NeighbourPredictionMode]
            raise ValueError(unknown("neighbour prediction", mode, modes)) from None

    @functools.cached_property
    def goals(self) -> GoalsConfig:
        return goals_config(self.options.get(GOALS), self.options.get(GOAL_WEIGHTS), self.env)

    def _weights(self, given: Path | None, env_name: str, model: str, shipped: bool) -> WeightsConfig | None:
        """A trained model directory: the option, else ``$env_name``, else the shipped one (None when nothing
        is shipped), checked (``WeightsError`` names the directory) and fingerprinted."""
        requested = str(given) if given is not None else self.env.get(env_name)
        if not requested and not shipped:
            return None
        chosen = Path(requested) if requested else shipped_weights_dir(model)
        load_weights(chosen, expected_model=model)
        return WeightsConfig(weights_sha256=weights_sha256(chosen), weights_dir=str(chosen))

    @functools.cached_property
    def gnp_weights(self) -> WeightsConfig:
        """The ``gnp`` model: ``--gnp-weights``, ``$LETSPI_GNP_WEIGHTS`` or the shipped one."""
        weights = self._weights(self.options.get(GNP_WEIGHTS), GNP_WEIGHTS_ENV, "gnp", shipped=True)
        assert weights is not None
        return weights

    @functools.cached_property
    def mlp_weights(self) -> WeightsConfig:
        """The ``mlp`` regressor: ``--mlp-weights`` or ``$LETSPI_MLP_WEIGHTS`` (nothing is shipped)."""
        weights = self._weights(self.options.get(MLP_WEIGHTS), MLP_WEIGHTS_ENV, "param-mlp", shipped=False)
        if weights is None:
            raise ValueError(f"the mlp planner needs trained weights: --mlp-weights DIR or ${MLP_WEIGHTS_ENV} "
                             "(train them with `letspi train mlp`)")
        return weights

    def llm(self, spec: str) -> LlmConfig:
        """The model ``spec`` with its weights fingerprint (local files only) and the prompt fingerprint."""
        parsed = parse_spec(spec)
        kind = backend_kind(parsed.kind)
        model_sha = model_path = adapter_sha = adapter_path = runtime = None
        if kind.local_weights is not None:
            path = kind.local_weights(parsed)
            if parsed.kind == "llamacpp":
                llama_runtime = LlamaRuntime.from_env(dict(self.env))
                runtime = llama_runtime.identity()
                # the file llama.cpp will run: its F16 copy where the probe saw its quantized kernels fault here
                path = runnable_model(path, flash_attn=llama_runtime.flash_attn)
                adapter = locate_adapter(parsed.model, self.env)  # $LETSPI_LLM_ADAPTER or the shipped one
                if adapter is not None:
                    adapter_sha, adapter_path = file_sha256(adapter), str(adapter)
            model_sha, model_path = path_sha256(path), str(path)
        style = self.options.get(PROMPT_STYLE)
        if style is None:  # what the adapter was trained on (compact for an adapter that does not say)
            trained = adapter_prompt_style(Path(adapter_path)) if adapter_path is not None else None
            style = (trained or "compact") if parsed.kind == "llamacpp" and is_fine_tuned(parsed.model) else "paper"
        if style not in PROMPT_STYLES:
            raise ValueError(unknown("prompt style", style, PROMPT_STYLES))
        return LlmConfig(spec=str(parsed), backend=installed_origin(parsed.kind), model_sha256=model_sha,
                         model_path=model_path, adapter_sha256=adapter_sha, adapter_path=adapter_path, runtime=runtime,
                         prompt_style=style,  # type: ignore[arg-type]
                         prompt_sha256=self._prompt_sha, cache=self.options.get(LLM_CACHE),
                         timeout_s=self.options.get(LLM_TIMEOUT))

    @functools.cached_property
    def _prompt_sha(self) -> str:
        return prompt_sha256()

    def decision(self, prompt_style: str, *, gate: bool = True, always: bool = False,
                 verify: bool = False) -> DecisionConfig | None:
        """The decision step (``--decide``; default: on for the choice style, or ``always``); the gate only
        where ``gate`` (the fast phase and ``sf-check``) and ``--gate`` allow it; the verification of a
        model's choice where ``verify`` (the fast phase's choice style) and ``--verify`` allow it."""
        o = self.options
        decide, risk_model = o.get(DECIDE), o.get(RISK_MODEL)
        on = decide if decide is not None else (always or prompt_style == "choice")
        if prompt_style == "choice" and not on:
            raise ValueError("the choice prompt style needs the decision step's presets (drop --no-decide)")
        if not on:
            return None
        threshold = None
        if gate and o.get(GATE):
            given = o.get(GATE_THRESHOLD)
            threshold = given if given is not None else recommended_threshold(risk_model)
        return DecisionConfig.resolve(o.get(PRESETS), o.get(ADVERSE), threshold, risk_model,
                                      verify=verify and prompt_style == "choice" and o.get(VERIFY),
                                      keep_lane=o.get(KEEP_LANE), idm_fallback=o.get(IDM_FALLBACK))

    def memory_phase(self, *, spec: str | None = None, max_iterations: int | None = None,
                     goal_adjustment: bool | None = None) -> MemoryPhaseConfig:
        """The collection configuration (defaults from the options)."""
        iterations = self.options.get(MAX_REFINEMENTS) if max_iterations is None else max_iterations
        llm = self.llm(spec or self.options.get(LLM))
        return MemoryPhaseConfig(
            llm=llm, goals=self.goals, neighbours=self.neighbours,
            sf_params=self.sf_params, reflection=ReflectionThresholds(max_iterations=iterations),
            goal_adjustment=self.options.get(GOAL_ADJUSTMENT) if goal_adjustment is None else goal_adjustment,
            decision=self.decision(llm.prompt_style, gate=False),
        )

    def memory_ref(self) -> MemoryRef:
        """A snapshot of the memories ``--memory`` (restricted to ``--memory-key``) offers now."""
        path = self.options.get(MEMORY)
        if path is None:
            raise ValueError("letspi-fast and letspi-fs need a memory bank: --memory FILE "
                             "(build one with `letspi collect`)")
        if not Path(path).exists():
            raise FileNotFoundError(f"{path}: no memory bank (build one with `letspi collect`)")
        key = self.options.get(MEMORY_KEY)
        with MemoryBank.open(path, readonly=True) as bank:
            ids, sha = bank.snapshot(key)
        return MemoryRef(path=str(path), collection_key=key, snapshot_sha256=sha, n_memories=len(ids),
                         allow_same_vehicle=self.options.get(ALLOW_SAME_VEHICLE),
                         subset_fraction=self.options.get(MEMORY_FRACTION), subset_seed=self.options.get(MEMORY_SEED))
