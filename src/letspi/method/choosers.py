"""Choosers without a language model: what picks a preset where the risk gate fires, in place of the model.

Each runs under the same presets, checks, gate, verification and shield as ``letspi-fast`` (``FastPhase.chooser``),
so a difference in outcome is the choice alone. docs/decisions.md compares them.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Final, Protocol

import numpy as np

from letspi.learned.trees import TreeEnsemble
from letspi.method.decide import DEFAULT_NAME, GATE_FEATURE_NAMES, OptionChecks, gate_features, rule_choice
from letspi.scenario.types import ScenarioBatch

TEACHER_FILE: Final = "teacher.json"
TEACHER_FORMAT: Final = "letspi-teacher/1"
#: the outcomes whose probabilities the teacher estimates per preset (``OptionOutcomes`` columns)
TEACHER_TARGETS: Final[tuple[str, ...]] = ("at_fault", "collision", "success")
#: the chooser names of ``letspi-fast --chooser`` that need no language model
CONSTANT_PREFIX: Final = "constant-"


class Chooser(Protocol):
    """Picks a preset per scenario from what the planner knows at t = 0 (no model call)."""

    def choose(self, history: ScenarioBatch, checks: OptionChecks, risk: np.ndarray) -> np.ndarray:
        """(B,) preset indices into ``checks.names`` from the presets' checks (B, K) and risk scores (B,)."""
        ...


@dataclass(frozen=True)
class ConstantChooser:
    """The same preset everywhere (by name; it must be one of the presets)."""

    option: str

    def choose(self, history: ScenarioBatch, checks: OptionChecks, risk: np.ndarray) -> np.ndarray:
        if self.option not in checks.names:
            raise ValueError(f"constant chooser: {self.option!r} is not a preset ({', '.join(checks.names)})")
        return np.full(len(history), checks.names.index(self.option), dtype=np.int64)


@dataclass(frozen=True)
class RuleChooser:
    """``sf-check``'s rule (``letspi.method.decide.rule_choice``)."""

    def choose(self, history: ScenarioBatch, checks: OptionChecks, risk: np.ndarray) -> np.ndarray:
        return rule_choice(checks.predicted_safe, checks.adverse_failed, checks.progress_m).astype(np.int64)


def cautious_choice(checks: OptionChecks) -> np.ndarray:
    """(B,) the rule's choice, except where the defaults fail a check and no preset fails fewer: there the
    tied preset (same number of failed checks) with the most predicted progress other than the defaults
    (the defaults where none ties)."""
    failed = checks.failed_checks()
    rule = rule_choice(checks.predicted_safe, checks.adverse_failed, checks.progress_m)
    tied = failed == failed.min(axis=1, keepdims=True)
    others = tied.copy()
    others[:, 0] = False
    key = np.where(others, np.nan_to_num(np.asarray(checks.progress_m, dtype=np.float64), nan=-1e3), -np.inf)
    alternative = np.argmax(key, axis=1)
    doubt = tied[:, 0] & (failed[:, 0] > 0) & others.any(axis=1)
    out: np.ndarray = np.where(doubt, alternative, rule).astype(np.int64)
    return out


@dataclass(frozen=True)
class CautiousChooser:
    """The rule with a cautious tie-break (``cautious_choice``)."""

    def choose(self, history: ScenarioBatch, checks: OptionChecks, risk: np.ndarray) -> np.ndarray:
        return cautious_choice(checks)


@dataclass(frozen=True)
class ConstantScore:
    """A model of an outcome that never varied in training: its rate, everywhere."""

    p: float

    def score(self, x: np.ndarray) -> np.ndarray:
        return np.full(len(x), self.p)


OutcomeModel = TreeEnsemble | ConstantScore


def teacher_feature_names(presets: Sequence[str], adverse_names: Sequence[str]) -> tuple[str, ...]:
    """The teacher's inputs: the gate's features, the risk score, and per preset whether it passes the
    prediction, each adverse future it fails, and its predicted progress beyond the defaults' [m]."""
    return (*GATE_FEATURE_NAMES, "risk",
            *(f"{p}_predicted_safe" for p in presets),
            *(f"{p}_fails_{a}" for p in presets for a in adverse_names),
            *(f"{p}_progress_gain_m" for p in presets))


def teacher_features(gate_x: np.ndarray, risk: np.ndarray, predicted_safe: np.ndarray, adverse_failed: np.ndarray,
                     progress_m: np.ndarray) -> np.ndarray:
    """(B, D) the teacher's inputs (``teacher_feature_names``) from the gate's features (B, G), the risk
    scores (B,), and per preset: predicted_safe (B, K), adverse_failed (B, K, A), progress_m (B, K)."""
    b = len(risk)
    progress = np.asarray(progress_m, dtype=np.float64)
    return np.concatenate([np.asarray(gate_x, dtype=np.float64), np.asarray(risk, dtype=np.float64)[:, None],
                           np.asarray(predicted_safe, dtype=np.float64),
                           np.asarray(adverse_failed, dtype=np.float64).reshape(b, -1),
                           progress - progress[:, :1]], axis=1)


@dataclass(frozen=True)
class Teacher:
    """The expected-utility policy of the choice labels: per preset, P(at-fault contact), P(contact) and
    P(success) (``models[target][k]``), choosing the highest ``-at_fault P(at fault) - contact P(contact) +
    P(success) + progress_per_m (progress - the defaults' progress)``, the defaults on a tie."""

    presets: tuple[str, ...]
    adverse_names: tuple[str, ...]
    weights: dict[str, float]
    models: dict[str, tuple[OutcomeModel, ...]]
    provenance: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if set(self.models) != set(TEACHER_TARGETS):
            raise ValueError(f"a teacher needs models of {TEACHER_TARGETS}, got {sorted(self.models)}")
        if any(len(m) != len(self.presets) for m in self.models.values()):
            raise ValueError(f"a teacher needs one model per preset ({len(self.presets)}) and outcome")
        if set(self.weights) != {"at_fault", "contact", "progress_per_m"}:
            raise ValueError(f"teacher weights must be at_fault, contact, progress_per_m; got {sorted(self.weights)}")

    @property
    def feature_names(self) -> tuple[str, ...]:
        return teacher_feature_names(self.presets, self.adverse_names)

    def probabilities(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """(B, K) per outcome from the inputs x (B, D)."""
        xs = np.asarray(x, dtype=np.float64)
        if xs.ndim != 2 or xs.shape[1] != len(self.feature_names):
            raise ValueError(f"the teacher expects (B, {len(self.feature_names)}) inputs, got {xs.shape}")
        return {t: np.stack([m.score(xs) for m in self.models[t]], axis=1) for t in TEACHER_TARGETS}

    def expected_utility(self, x: np.ndarray) -> np.ndarray:
        """(B, K) the expected utility of each preset (the progress gains are columns of x)."""
        p = self.probabilities(x)
        gain = np.asarray(x, dtype=np.float64)[:, -len(self.presets):]
        w = self.weights
        out: np.ndarray = (-w["at_fault"] * p["at_fault"] - w["contact"] * p["collision"] + p["success"]
                           + w["progress_per_m"] * np.nan_to_num(gain))
        return out

    def choose_x(self, x: np.ndarray) -> np.ndarray:
        """(B,) the preset of the highest expected utility (the first, i.e. the defaults, on a tie)."""
        out: np.ndarray = np.argmax(self.expected_utility(x), axis=1).astype(np.int64)
        return out

    def inputs(self, history: ScenarioBatch, checks: OptionChecks, risk: np.ndarray) -> np.ndarray:
        """(B, D) the inputs of B scenarios from their presets' checks and risk scores."""
        if tuple(checks.names) != self.presets:
            raise ValueError(f"the teacher was trained on the presets {self.presets}, the planner has {checks.names}")
        if tuple(checks.adverse_names) != self.adverse_names:
            raise ValueError(f"the teacher reads the adverse futures {self.adverse_names}, the checks have "
                             f"{checks.adverse_names} (the teacher needs the adverse futures: drop --no-adverse)")
        gate_x = gate_features(history, checks.predicted_safe[:, 0], checks.adverse_failed[:, 0], checks.adverse_names)
        return teacher_features(gate_x, risk, checks.predicted_safe, checks.adverse_failed, checks.progress_m)

    def to_json(self) -> dict[str, Any]:
        def model(m: OutcomeModel) -> dict[str, Any]:
            if isinstance(m, ConstantScore):
                return {"constant": m.p}
            data = m.to_json()
            data.pop("provenance", None)
            return data

        return {"format": TEACHER_FORMAT, "presets": list(self.presets), "adverse_names": list(self.adverse_names),
                "weights": self.weights, "feature_names": list(self.feature_names),
                "models": {t: [model(m) for m in self.models[t]] for t in TEACHER_TARGETS},
                "provenance": self.provenance}

    @classmethod
    def from_json(cls, data: dict[str, Any], source: str = "teacher") -> Teacher:
        if data.get("format") != TEACHER_FORMAT:
            raise ValueError(f"{source}: format {data.get('format')!r}, expected {TEACHER_FORMAT!r}")
        try:
            presets, adverse = tuple(data["presets"]), tuple(data["adverse_names"])
            names = teacher_feature_names(presets, adverse)
            if tuple(data["feature_names"]) != names:
                raise ValueError(f"{source}: its feature names are not the teacher's inputs")

            def model(m: dict[str, Any]) -> OutcomeModel:
                if "constant" in m:
                    return ConstantScore(float(m["constant"]))
                ens = TreeEnsemble.from_json({**m, "provenance": {}}, source)
                if ens.feature_names != names:
                    raise ValueError(f"{source}: a model's feature names are not the teacher's inputs")
                return ens

            models = {t: tuple(model(m) for m in data["models"][t]) for t in TEACHER_TARGETS}
            return cls(presets, adverse, {k: float(v) for k, v in data["weights"].items()}, models,
                       dict(data.get("provenance", {})))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"{source}: not a teacher ({exc})") from exc


def load_teacher(path: Path | None = None) -> tuple[Teacher, str]:
    """The teacher (shipped, or ``path``) and the SHA-256 of its file."""
    if path is None:
        text, where = resources.files("letspi.data").joinpath(TEACHER_FILE).read_text(), f"letspi/data/{TEACHER_FILE}"
    else:
        text, where = Path(path).read_text(), str(path)
    return Teacher.from_json(json.loads(text), where), hashlib.sha256(text.encode()).hexdigest()


@dataclass(frozen=True)
class TeacherChooser:
    """The teacher as a chooser (``Teacher.choose_x`` on the planner's checks and risk scores)."""

    teacher: Teacher

    def choose(self, history: ScenarioBatch, checks: OptionChecks, risk: np.ndarray) -> np.ndarray:
        return self.teacher.choose_x(self.teacher.inputs(history, checks, risk))


#: ``letspi-fast --chooser`` names: the model (default), the model on another window's prompt, and the
#: choosers of this module
MODEL_CHOOSER: Final = "model"
SHUFFLED_CHOOSER: Final = "shuffled"
CHOOSER_NAMES: Final[tuple[str, ...]] = (MODEL_CHOOSER, "rule", f"{CONSTANT_PREFIX}{DEFAULT_NAME}",
                                         f"{CONSTANT_PREFIX}ease", "cautious", "teacher", SHUFFLED_CHOOSER)


def uses_model(name: str) -> bool:
    """Whether the chooser ``name`` asks the language model."""
    return name in (MODEL_CHOOSER, SHUFFLED_CHOOSER)


def make_chooser(name: str, teacher: Teacher | None = None) -> Chooser:
    """The chooser ``name`` of ``CHOOSER_NAMES`` that needs no model (``teacher``: for ``teacher``)."""
    if name == "rule":
        return RuleChooser()
    if name == "cautious":
        return CautiousChooser()
    if name == "teacher":
        if teacher is None:
            raise ValueError("the teacher chooser needs a teacher (letspi/data/teacher.json or --teacher)")
        return TeacherChooser(teacher)
    if name.startswith(CONSTANT_PREFIX) and name in CHOOSER_NAMES:
        return ConstantChooser(name[len(CONSTANT_PREFIX):])
    raise ValueError(f"{name!r} is not a chooser without a model; choosers: {', '.join(CHOOSER_NAMES)}")
