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
    """The memories a fast planner may retrieve: ``collection_key`` (None: any), ``snapshot_sha256`` of the
    retrievable rows when the planner was built (a changed bank gives another key), ``allow_same_vehicle``
    (the query's own vehicle: a leak), the memory-size ablation's ``subset_fraction`` / ``subset_seed``."""

    cosmetic: ClassVar[frozenset[str]] = frozenset({"path", "n_memories"})

    path: str
    collection_key: str | None = None
    snapshot_sha256: str
    n_memories: int
    allow_same_vehicle: bool = False
    subset_fraction: float | None = None
    subset_seed: int = 0


class DecisionConfig(Config):
    """LetsPi's decision step (``letspi.method.decide``): preset values, ``adverse`` settings (None: the
    prediction only), the risk model's SHA-256, ``gate_threshold`` (None: always consult) and ``verify``
    (``Decider.verified``; None: the model's answer stands, and the field stays out of the key)."""

    cosmetic: ClassVar[frozenset[str]] = frozenset({"presets_source", "risk_model_path"})
    omitted_when_none: ClassVar[frozenset[str]] = frozenset({"verify", "keep_lane", "idm_fallback"})

    preset_names: tuple[str, ...]
    preset_values: tuple[tuple[float, ...], ...]
    presets_source: str = "shipped"
    adverse: AdverseSettings | None = AdverseSettings()
    risk_model_sha256: str
    risk_model_path: str = "shipped"
    gate_threshold: float | None = None
    verify: bool | None = None
    keep_lane: bool | None = None  # a preset changing lane only where the lane keepers fail more checks
    idm_fallback: bool | None = None  # the shield's last alternative: an IDM plan behind the in-lane leader

    def table(self) -> OptionTable:
        return OptionTable(self.preset_names, np.asarray(self.preset_values, dtype=np.float64))

    @classmethod
    def resolve(cls, presets_file: Path | None, adverse: bool, gate_threshold: float | None,
                risk_model_file: Path | None, verify: bool = False, keep_lane: bool = False,
                idm_fallback: bool = False) -> DecisionConfig:
        """From files (default: the shipped presets and risk model) and switches."""
        table, _ = load_presets(presets_file)
        _, sha = load_risk_model(risk_model_file)
        return cls(preset_names=table.names, preset_values=tuple(tuple(float(x) for x in row) for row in table.values),
                   presets_source="shipped" if presets_file is None else str(presets_file),
                   adverse=AdverseSettings() if adverse else None, risk_model_sha256=sha,
                   risk_model_path="shipped" if risk_model_file is None else str(risk_model_file),
                   gate_threshold=gate_threshold, verify=True if verify else None,
                   keep_lane=True if keep_lane else None, idm_fallback=True if idm_fallback else None)

    def decider(self, params: SocialForceParams, thresholds: ReflectionThresholds) -> Decider:
        """The decision step for planners whose defaults are ``params``."""
        path = None if self.risk_model_path == "shipped" else Path(self.risk_model_path)
        model, sha = load_risk_model(path)
        if sha != self.risk_model_sha256:
            raise ValueError(f"the risk model {self.risk_model_path} changed since the configuration was made "
                             f"({self.risk_model_sha256[:12]} -> {sha[:12]})")
        return Decider(with_defaults(self.table(), params), float(params.r_col_m), thresholds, self.adverse,
                       RiskGate(model, self.gate_threshold), verify=bool(self.verify), keep_lane=bool(self.keep_lane),
                       idm_fallback=bool(self.idm_fallback))


class MemoryPhaseConfig(Config):
    """LetsPi's memory collection phase; its key identifies the experiences it stores. ``sf_params`` supplies
    ``r_col_m`` (the LLM sets the other six) and the fallback parameters of a failed call."""

    omitted_when_none: ClassVar[frozenset[str]] = frozenset({"decision"})

    llm: LlmConfig
    goals: GoalsConfig
    neighbours: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    sf_params: SfParamsConfig
    reflection: ReflectionThresholds = Field(default_factory=ReflectionThresholds)
    goal_adjustment: bool = True
    decision: DecisionConfig | None = None  # presets and adverse futures in the reflection (None: the paper's)
