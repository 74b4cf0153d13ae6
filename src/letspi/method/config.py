"""The configurations of LetsPi's method: the memory phase, the memories a fast planner may retrieve, and
the decision step."""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

import numpy as np
from pydantic import Field

from letspi.keyed import Config
from letspi.llm.config import LlmConfig
from letspi.method.decide import Decider, OptionTable, RiskGate, load_presets, load_risk_model, with_defaults
from letspi.method.thresholds import ReflectionThresholds
from letspi.physics.config import GoalsConfig, SfParamsConfig
from letspi.physics.neighbours import NeighbourPredictionMode
from letspi.physics.params import SocialForceParams
from letspi.safety.adverse import AdverseSettings


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
    omitted_when_none: ClassVar[frozenset[str]] = frozenset({"verify"})

    preset_names: tuple[str, ...]
    preset_values: tuple[tuple[float, ...], ...]
    presets_source: str = "shipped"
    adverse: AdverseSettings | None = AdverseSettings()
    risk_model_sha256: str
    risk_model_path: str = "shipped"
    gate_threshold: float | None = None
    verify: bool | None = None

    def table(self) -> OptionTable:
        return OptionTable(self.preset_names, np.asarray(self.preset_values, dtype=np.float64))

    @classmethod
    def resolve(cls, presets_file: Path | None, adverse: bool, gate_threshold: float | None,
                risk_model_file: Path | None, verify: bool = False) -> DecisionConfig:
        """From files (default: the shipped presets and risk model) and switches."""
        table, _ = load_presets(presets_file)
        _, sha = load_risk_model(risk_model_file)
        return cls(preset_names=table.names, preset_values=tuple(tuple(float(x) for x in row) for row in table.values),
                   presets_source="shipped" if presets_file is None else str(presets_file),
                   adverse=AdverseSettings() if adverse else None, risk_model_sha256=sha,
                   risk_model_path="shipped" if risk_model_file is None else str(risk_model_file),
                   gate_threshold=gate_threshold, verify=True if verify else None)

    def decider(self, params: SocialForceParams, thresholds: ReflectionThresholds) -> Decider:
        """The decision step for planners whose defaults are ``params``."""
        path = None if self.risk_model_path == "shipped" else Path(self.risk_model_path)
        model, sha = load_risk_model(path)
        if sha != self.risk_model_sha256:
            raise ValueError(f"the risk model {self.risk_model_path} changed since the configuration was made "
                             f"({self.risk_model_sha256[:12]} -> {sha[:12]})")
        return Decider(with_defaults(self.table(), params), float(params.r_col_m), thresholds, self.adverse,
                       RiskGate(model, self.gate_threshold), verify=bool(self.verify))


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
