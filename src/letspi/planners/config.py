"""Frozen configurations: everything that changes an answer, and the content hash that identifies it.

A planner, a memory-collection run and an evaluation are built from one of these objects and are
identified by its ``key()``: the first 16 hex digits of the SHA-256 of the configuration's
canonical JSON (sorted keys, no cosmetic fields). Two configurations with equal keys give the same
answers; anything that can change an answer is a field:

* LLM: the model spec, a fingerprint of the weights when they are local files (GGUF, LoRA adapter),
  the decoding settings, whether a JSON schema constrains the reply, the number of attempts, and a
  fingerprint of the prompt text (template files and the code that renders the scene);
* physics: the neighbour prediction mode, the social force parameter *values* (not the file they
  came from), the goal source with a fingerprint of its weights;
* LetsPi: reflection thresholds and iteration budget, goal adjustment on/off, top-k, and the
  identity of the memories a fast planner may retrieve (a snapshot fingerprint of the bank's rows);
* evaluation: the dataset digest and the metrics configuration (``letspi.evaluation.harness``).

Cosmetic fields (a file path whose content is fingerprinted elsewhere, a timeout, the response
cache switch) are recorded in ``run.json`` for the reader but left out of the key: they cannot change
an answer. ``diff`` names the fields in which two configurations differ, for refusal messages.

This module holds the base class and the building blocks planners share. Each planner's own
configuration (``CvConfig``, ``SfConfig``, ...) sits beside the planner in its module, and
``letspi.assembly.planner_table`` lists every kind with how it is resolved and built.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from enum import Enum
from pathlib import Path
from typing import Any, ClassVar, Literal, Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from letspi.llm.client import RetryPolicy
from letspi.llm.types import DecodingSettings
from letspi.method.decide import Decider, OptionTable, RiskGate, load_presets, load_risk_model, with_defaults
from letspi.method.thresholds import ReflectionThresholds
from letspi.physics.neighbours import NeighbourPredictionMode
from letspi.physics.params import PARAM_NAMES, SocialForceParams
from letspi.planners.options import PlannerOption, file_option
from letspi.safety.adverse import AdverseSettings

KEY_CHARS = 16


def _identity(value: Any) -> Any:
    if isinstance(value, Config):
        return value.identity()
    if isinstance(value, BaseModel):
        return value.model_dump(mode="json")
    if isinstance(value, Enum):
        return value.value
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, Mapping):
        return {str(k): _identity(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_identity(v) for v in value]
    return value


def canonical_json(value: Any) -> str:
    """Sorted-key, whitespace-free JSON: the text that is hashed."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False)


def key_of(identity: Any) -> str:
    """The key of an identity dict (``Config.identity()``)."""
    return hashlib.sha256(canonical_json(identity).encode("utf-8")).hexdigest()[:KEY_CHARS]


class Config(BaseModel):
    """Base of every configuration: frozen, no unknown fields, a content key."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    #: fields that locate or label but cannot change an answer (recorded, not hashed)
    cosmetic: ClassVar[frozenset[str]] = frozenset()
    #: fields left out of the key while they are None: a feature added later, off, keeps the keys it had
    omitted_when_none: ClassVar[frozenset[str]] = frozenset()

    def identity(self) -> dict[str, Any]:
        """What the key hashes: every non-cosmetic field, nested configurations by their identity."""
        return {name: _identity(getattr(self, name)) for name in type(self).model_fields
                if name not in self.cosmetic and not (name in self.omitted_when_none and getattr(self, name) is None)}

    def key(self) -> str:
        """16 hex digits identifying this configuration's answers."""
        return key_of(self.identity())

    def record(self) -> dict[str, Any]:
        """Everything, cosmetic fields included (what ``run.json`` stores)."""
        return self.model_dump(mode="json")


def diff(old: Mapping[str, Any], new: Mapping[str, Any], prefix: str = "") -> list[str]:
    """Dotted field paths whose values differ between two identity dicts, with both values."""
    out: list[str] = []
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k, "<absent>"), new.get(k, "<absent>")
        path = f"{prefix}{k}"
        if isinstance(a, Mapping) and isinstance(b, Mapping):
            out += diff(a, b, prefix=f"{path}.")
        elif a != b:
            out.append(f"{path}: {_short(a)} -> {_short(b)}")
    return out


def _short(value: Any) -> str:
    text = json.dumps(value, sort_keys=True) if not isinstance(value, str) else value
    return text if len(text) <= 60 else text[:57] + "..."


# ------------------------------------------------------------------------------------------------
# Building blocks
# ------------------------------------------------------------------------------------------------


class SfParamsConfig(Config):
    """Social force parameter values (one set, ``PARAM_NAMES`` -> value) and, cosmetically, their file."""

    cosmetic: ClassVar[frozenset[str]] = frozenset({"source"})

    values: dict[str, float]
    source: str = "shipped"

    @field_validator("values")
    @classmethod
    def _all_parameters(cls, values: dict[str, float]) -> dict[str, float]:
        if set(values) != set(PARAM_NAMES):
            raise ValueError(f"social force parameters must be exactly {PARAM_NAMES}, got {sorted(values)}")
        return {name: float(values[name]) for name in PARAM_NAMES}

    @classmethod
    def of(cls, params: SocialForceParams, source: str) -> SfParamsConfig:
        return cls(values=params.as_dict(), source=source)

    def params(self) -> SocialForceParams:
        return SocialForceParams(**self.values)


GoalSource = Literal["learned", "kinematic", "oracle"]


class GoalsConfig(Config):
    """Where goals come from. ``learned`` carries the fingerprint of the weights it uses; when no
    weights are found it falls back to ``kinematic`` and says so (``fallback_reason``)."""

    cosmetic: ClassVar[frozenset[str]] = frozenset({"weights_dir", "fallback_reason"})

    source: GoalSource = "learned"
    weights_sha256: str | None = None
    weights_dir: str | None = None
    fallback_reason: str | None = None

    @property
    def reads_future(self) -> bool:
        return self.source == "oracle"


class WeightsConfig(Config):
    """A trained model directory, identified by the fingerprint of its files."""

    cosmetic: ClassVar[frozenset[str]] = frozenset({"weights_dir"})

    weights_sha256: str
    weights_dir: str


class LlmConfig(Config):
    """One language model as used by a phase: model, weights, decoding, prompt text, retries.

    ``adapter_sha256`` / ``adapter_path``: the LoRA adapter llama.cpp applies (the fine-tuned
    ``smollm2-135m-letspi``); ``prompt_style``: ``paper`` (physics + fast prompts with few-shot
    memories) or ``compact`` (``letspi.llm.compact``, what the fine-tuned model was trained on);
    ``runtime``: the embedded model's llama.cpp version and attention path
    (``letspi.llm.backends.llamacpp.LlamaRuntime.identity``; None for servers).
    """

    cosmetic: ClassVar[frozenset[str]] = frozenset({"timeout_s", "cache", "model_path", "adapter_path"})

    spec: str
    model_sha256: str | None = None
    model_path: str | None = None
    adapter_sha256: str | None = None
    adapter_path: str | None = None
    prompt_style: Literal["paper", "compact", "choice"] = "paper"
    runtime: str | None = None
    temperature: float = DecodingSettings.temperature
    seed: int = DecodingSettings.seed
    max_tokens: int = DecodingSettings.max_tokens
    use_schema: bool = True
    max_attempts: int = Field(default=RetryPolicy.max_attempts, ge=1)
    prompt_sha256: str
    timeout_s: float = RetryPolicy.timeout_s
    cache: bool = True

    def decoding(self) -> DecodingSettings:
        return DecodingSettings(temperature=self.temperature, seed=self.seed, max_tokens=self.max_tokens)


class MemoryRef(Config):
    """The memories a fast planner may retrieve, pinned by a fingerprint of the bank's rows.

    collection_key: only memories collected under this configuration (None: any configuration).
    snapshot_sha256: fingerprint of every retrievable row (id, scenario digest, configuration) when
        the planner was built; a bank that gained or lost memories gives another key.
    allow_same_vehicle: False excludes memories of the query's own ego vehicle with an overlapping
        window (a leak of the query's future); True keeps them (labelled in results).
    subset_fraction / subset_seed: the memory-size ablation's reproducible subset (None: all).
    """

    cosmetic: ClassVar[frozenset[str]] = frozenset({"path", "n_memories"})

    path: str
    collection_key: str | None = None
    snapshot_sha256: str
    n_memories: int
    allow_same_vehicle: bool = False
    subset_fraction: float | None = None
    subset_seed: int = 0


class DecisionConfig(Config):
    """LetsPi's decision step (``letspi.method.decide``): the preset values, the adverse futures' settings
    (None: checks against the prediction only, the "without adverse futures" ablation), the risk model
    (its SHA-256; its score is the gate's and the choice prompt's risk) and the gate's threshold (None:
    the model is asked on every scenario). ``verify`` (the fast phase): a model's choice that fails more
    checks than another preset is replaced by the rule's choice (``Decider.verified``); None: the model's
    answer stands. A planner without it plans exactly as before the decision step existed, under the same
    key, and ``verify`` None keeps the keys of before verification existed."""

    cosmetic: ClassVar[frozenset[str]] = frozenset({"presets_source", "risk_model_path"})
    omitted_when_none: ClassVar[frozenset[str]] = frozenset({"verify", "keep_lane"})

    preset_names: tuple[str, ...]
    preset_values: tuple[tuple[float, ...], ...]
    presets_source: str = "shipped"
    adverse: AdverseSettings | None = AdverseSettings()
    risk_model_sha256: str
    risk_model_path: str = "shipped"
    gate_threshold: float | None = None
    verify: bool | None = None
    keep_lane: bool | None = None  # a preset changing lane only where the lane keepers fail more checks

    def table(self) -> OptionTable:
        return OptionTable(self.preset_names, np.asarray(self.preset_values, dtype=np.float64))

    @classmethod
    def resolve(cls, presets_file: Path | None, adverse: bool, gate_threshold: float | None,
                risk_model_file: Path | None, verify: bool = False, keep_lane: bool = False) -> DecisionConfig:
        """From files (default: the shipped presets and risk model) and switches."""
        table, _ = load_presets(presets_file)
        _, sha = load_risk_model(risk_model_file)
        return cls(preset_names=table.names, preset_values=tuple(tuple(float(x) for x in row) for row in table.values),
                   presets_source="shipped" if presets_file is None else str(presets_file),
                   adverse=AdverseSettings() if adverse else None, risk_model_sha256=sha,
                   risk_model_path="shipped" if risk_model_file is None else str(risk_model_file),
                   gate_threshold=gate_threshold, verify=True if verify else None,
                   keep_lane=True if keep_lane else None)

    def decider(self, params: SocialForceParams, thresholds: ReflectionThresholds) -> Decider:
        """The decision step for planners whose defaults are ``params``."""
        path = None if self.risk_model_path == "shipped" else Path(self.risk_model_path)
        model, sha = load_risk_model(path)
        if sha != self.risk_model_sha256:
            raise ValueError(f"the risk model {self.risk_model_path} changed since the configuration was made "
                             f"({self.risk_model_sha256[:12]} -> {sha[:12]})")
        return Decider(with_defaults(self.table(), params), float(params.r_col_m), thresholds, self.adverse,
                       RiskGate(model, self.gate_threshold), verify=bool(self.verify), keep_lane=bool(self.keep_lane))


class MemoryPhaseConfig(Config):
    """LetsPi's memory collection phase: its key identifies the experiences it stores.

    ``reflection.max_iterations`` = 0 is the single-shot ``llm`` planner and the "w/o Ref" ablation;
    ``goal_adjustment`` False the "w/o GA" ablation. ``sf_params`` supplies ``r_col_m`` (the LLM sets
    the other six) and the fallback parameters of a failed call.
    """

    omitted_when_none: ClassVar[frozenset[str]] = frozenset({"decision"})

    llm: LlmConfig
    goals: GoalsConfig
    neighbours: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    sf_params: SfParamsConfig
    reflection: ReflectionThresholds = Field(default_factory=ReflectionThresholds)
    goal_adjustment: bool = True
    decision: DecisionConfig | None = None  # presets and adverse futures in the reflection (None: the paper's)


GOAL_SOURCES: tuple[str, ...] = ("learned", "kinematic", "oracle")
GOAL_WEIGHTS_ENV = "LETSPI_GOAL_WEIGHTS"

# Options of the planners that predict goals and neighbours (every kind but human and cv) -----------
NEIGHBOURS = PlannerOption(
    "neighbour_mode", str, NeighbourPredictionMode.IDM.value,
    "Neighbour prediction of the planners: ground_truth_oracle leaks the future (an upper bound, not a planner)",
    flag="--neighbours", choices=tuple(m.value for m in NeighbourPredictionMode))
GOALS = PlannerOption(
    "goals", str, "learned",
    "Goal source: learned (the goal predictor's weights, see --goal-weights), kinematic, or oracle (the true "
    "endpoint: leaks the future)", choices=GOAL_SOURCES)
GOAL_WEIGHTS = file_option(
    "goal_weights",
    f"Weights of the learned goal predictor (from `letspi train goals`; default: ${GOAL_WEIGHTS_ENV}, else the "
    "shipped ones)")
SF_PARAMS = file_option(
    "sf_params_file",
    "Fitted social force parameters JSON (from `letspi fit sf`; default: the shipped fit); the LLM planners take "
    "r_col and their fallback from it", flag="--sf-params")
#: what every planner that predicts goals and neighbours reads
PREDICTION_OPTIONS: tuple[PlannerOption[Any], ...] = (NEIGHBOURS, GOALS, GOAL_WEIGHTS)
#: what the fixed-parameter social force planners read (``sf``, ``sf-opt``)
SOCIAL_FORCE_OPTIONS: tuple[PlannerOption[Any], ...] = (*PREDICTION_OPTIONS, SF_PARAMS)


# Options of the decision step (``DecisionConfig``: letspi-fast, letspi-memory, llm, letspi-fs, sf-check) ---------
DECIDE = PlannerOption[bool | None](
    "decide", bool | None, None,
    "LetsPi's decision step: presets checked against the prediction and the adverse futures, a risk gate "
    "(default: on for the choice prompt style and sf-check)")
PRESETS = file_option("presets_file", "Presets of the decision step (default: the shipped ones)", flag="--presets")
ADVERSE = PlannerOption("adverse", bool, True, "Decision step: check plans against the adverse futures too "
                        "(off: against the prediction only)")
GATE = PlannerOption("gate", bool, True, "Decision step: the risk gate of letspi-fast and sf-check (off: the model "
                     "is asked on every scenario)")
GATE_THRESHOLD = PlannerOption[float | None](
    "gate_threshold", float | None, None,
    "Decision step: the risk score above which the gate asks the model (default: the risk model's recommended "
    "threshold)")
RISK_MODEL = file_option("risk_model_file", "Decision step: the gate's risk model (default: the shipped one)",
                         flag="--risk-model")
VERIFY = PlannerOption("verify", bool, True, "Decision step of letspi-fast: a model's choice that fails more checks "
                       "than another preset is replaced by the rule's choice (off: the model's answer stands)")
KEEP_LANE = PlannerOption("keep_lane", bool, False, "Decision step: the rule, the verification and the shield take "
                          "a preset that changes lane only where every preset keeping the lane fails more checks")
DECISION_OPTIONS: tuple[PlannerOption[Any], ...] = (DECIDE, PRESETS, ADVERSE, GATE, GATE_THRESHOLD, RISK_MODEL, VERIFY,
                                                    KEEP_LANE)


class SocialForcePlannerFields(Config):
    """What every fixed-parameter social force planner is built from (``sf``, ``sf-opt``, ``mlp``)."""

    neighbours: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    goals: GoalsConfig
    sf_params: SfParamsConfig


class PlannerConfig(Protocol):
    """What every planner configuration offers: a frozen ``Config`` whose ``kind`` field is a literal
    naming its entry in ``letspi.assembly.planner_table``."""

    @property
    def kind(self) -> str: ...

    def identity(self) -> dict[str, Any]: ...

    def key(self) -> str: ...

    def record(self) -> dict[str, Any]: ...
