"""The decision step of LetsPi: named options, checked against what could happen, and a risk gate.

An option is one answer of the eight numbers the LLM chooses; an ``OptionTable`` names C of them, the fitted
defaults first. ``check_options`` plans every option on every scenario and checks each plan against the
prediction and the adverse futures (``letspi.safety.adverse``); ``rule_choice`` chooses without a model; the
``RiskGate`` decides whether the model is consulted at all.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path
from typing import Any, ClassVar, Final, Protocol

import numpy as np

from letspi.constants import DT_S
from letspi.learned.logistic import LogisticModel
from letspi.learned.trees import FORMAT as TREES_FORMAT
from letspi.learned.trees import TreeEnsemble
from letspi.llm.schema import FIELD_RANGES, NUMERIC_FIELDS
from letspi.method.reflection import simulate_proposal
from letspi.method.thresholds import ReflectionThresholds
from letspi.physics.goals import NEUTRAL_LANE_FACTOR, NEUTRAL_LON_FACTOR
from letspi.physics.params import SocialForceParams
from letspi.physics.types import NeighbourPrediction
from letspi.safety.adverse import ADVERSE_FUTURES, AdverseFuture, AdverseSettings, adverse_futures, check_futures
from letspi.scenario.risk_features import RISK_FEATURE_NAMES, risk_features
from letspi.scenario.types import ScenarioBatch

DEFAULT_NAME: Final = "default"
PRESETS_FILE: Final = "presets.json"
RISK_MODEL_FILE: Final = "risk_model.json"
PRESETS_FORMAT: Final = "letspi-presets/1"
_LOW = np.array([FIELD_RANGES[f][0] for f in NUMERIC_FIELDS])
_HIGH = np.array([FIELD_RANGES[f][1] for f in NUMERIC_FIELDS])


def defaults_vector(params: SocialForceParams) -> np.ndarray:
    """(8,) the fitted parameters with the neutral goal factors, in ``NUMERIC_FIELDS`` order."""
    values = {**params.as_dict(), "lon_factor": NEUTRAL_LON_FACTOR, "lane_factor": NEUTRAL_LANE_FACTOR}
    return np.clip(np.array([float(values[f]) for f in NUMERIC_FIELDS]), _LOW, _HIGH)


def params_of(values: np.ndarray, r_col_m: float) -> SocialForceParams:
    """(C, 8) option rows -> a (C,) parameter batch (``r_col_m`` fixed: the LLM does not choose it)."""
    v = np.asarray(values, dtype=np.float64).reshape(-1, len(NUMERIC_FIELDS))
    cols = {f: v[:, i].copy() for i, f in enumerate(NUMERIC_FIELDS[:6])}
    return SocialForceParams(**cols, r_col_m=np.full(len(v), float(r_col_m)))


@dataclass(frozen=True)
class OptionTable:
    """C named answers, (C, 8) values in ``NUMERIC_FIELDS`` order; option 0 is the defaults."""

    names: tuple[str, ...]
    values: np.ndarray

    def __post_init__(self) -> None:
        v = np.asarray(self.values, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != len(NUMERIC_FIELDS) or len(v) != len(self.names):
            raise ValueError(f"an option table needs (C, {len(NUMERIC_FIELDS)}) values for its {len(self.names)} "
                             f"names, got {v.shape}")
        if len(set(self.names)) != len(self.names):
            raise ValueError(f"option names repeat: {self.names}")

    def __len__(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"unknown option {name!r}; options: {', '.join(self.names)}") from None

    def subset(self, indices: Sequence[int]) -> OptionTable:
        """The options ``indices`` (in that order) as a table of their own."""
        idx = [int(i) for i in indices]
        return OptionTable(tuple(self.names[i] for i in idx), np.asarray(self.values, dtype=np.float64)[idx])

    def values_of(self, name: str) -> dict[str, float]:
        """The option's eight numbers by field name."""
        return dict(zip(NUMERIC_FIELDS, (float(x) for x in self.values[self.index(name)]), strict=True))

    def sha256(self) -> str:
        text = json.dumps({"names": list(self.names), "values": np.round(self.values, 9).tolist()}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()

    def to_json(self) -> dict[str, Any]:
        return {"names": list(self.names), "fields": list(NUMERIC_FIELDS), "values": self.values.tolist()}

    @classmethod
    def from_json(cls, data: dict[str, Any], source: str = "option table") -> OptionTable:
        if list(data.get("fields", NUMERIC_FIELDS)) != list(NUMERIC_FIELDS):
            raise ValueError(f"{source}: fields {data.get('fields')} are not {list(NUMERIC_FIELDS)}")
        try:
            return cls(tuple(str(n) for n in data["names"]), np.asarray(data["values"], dtype=np.float64))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"{source}: not an option table ({exc})") from exc


def _data_text(name: str) -> tuple[str, str]:
    return resources.files("letspi.data").joinpath(name).read_text(), f"letspi/data/{name}"


def load_presets(path: Path | None = None) -> tuple[OptionTable, dict[str, Any]]:
    """The presets (shipped, or ``path``) and their whole record (provenance)."""
    text, where = _data_text(PRESETS_FILE) if path is None else (Path(path).read_text(), str(path))
    record = json.loads(text)
    if record.get("format") != PRESETS_FORMAT:
        raise ValueError(f"{where}: format {record.get('format')!r}, expected {PRESETS_FORMAT!r}")
    table = OptionTable.from_json(record, where)
    if table.names[0] != DEFAULT_NAME:
        raise ValueError(f"{where}: the first preset must be {DEFAULT_NAME!r}, got {table.names[0]!r}")
    return table, record


def with_defaults(table: OptionTable, params: SocialForceParams) -> OptionTable:
    """``table`` with option 0 replaced by ``params`` (a planner with other ``sf`` parameters keeps its own)."""
    values = np.array(table.values, dtype=np.float64)
    values[0] = defaults_vector(params)
    return OptionTable(table.names, values)


@dataclass(frozen=True)
class OptionChecks:
    """Every option of a table planned and checked on B scenarios; (B, K) unless said. names (K,), adverse_names
    (A,); predicted_safe: passes the reflection's checks against the prediction; adverse_failed (B, K, A);
    progress_m: the plan's end x [m]; min_ttc_s: the smaller of front and rear TTC [s]; xy_m, vxy_mps
    (B, K, F, 2) the plans; goals_xy_m (B, K, 2) their adjusted goals."""

    names: tuple[str, ...]
    adverse_names: tuple[str, ...]
    predicted_safe: np.ndarray
    adverse_failed: np.ndarray
    progress_m: np.ndarray
    min_ttc_s: np.ndarray
    xy_m: np.ndarray
    vxy_mps: np.ndarray
    goals_xy_m: np.ndarray

    #: the fields with the scenario axis first
    ARRAYS: ClassVar[tuple[str, ...]] = ("predicted_safe", "adverse_failed", "progress_m", "min_ttc_s", "xy_m",
                                         "vxy_mps", "goals_xy_m")

    def take(self, rows: np.ndarray | Sequence[int] | slice) -> OptionChecks:
        """The checks of the selected scenarios (index array, mask or slice)."""
        return replace(self, **{f: getattr(self, f)[rows] for f in self.ARRAYS})

    def row(self, i: int) -> OptionChecks:
        """Scenario ``i``'s checks as a batch of one."""
        return self.take(slice(i, i + 1))

    def failed_checks(self) -> np.ndarray:
        """(B, K) how many checks each option fails (the prediction counts as one)."""
        out: np.ndarray = self.adverse_failed.sum(axis=2) + ~self.predicted_safe
        return out

    def passes_all(self) -> np.ndarray:
        """(B, K) the option passes the prediction and every adverse future."""
        out: np.ndarray = self.failed_checks() == 0
        return out

    def failed_names(self, i: int, k: int) -> list[str]:
        """The checks option ``k`` fails in scenario ``i`` ("predicted" first)."""
        out = [] if self.predicted_safe[i, k] else ["predicted"]
        return out + [a for a, bad in zip(self.adverse_names, self.adverse_failed[i, k], strict=True) if bad]


def peak_braking_mps2(vx0_mps: np.ndarray, plan_vxy_mps: np.ndarray) -> np.ndarray:
    """(R,) a plan's peak deceleration from the t = 0 speed [m/s^2] (as the reflection measures it)."""
    vx = np.concatenate([np.asarray(vx0_mps, dtype=np.float64)[:, None], plan_vxy_mps[..., 0]], axis=1)
    out: np.ndarray = np.nan_to_num(-np.diff(vx, axis=1) / DT_S, nan=np.inf).max(axis=1)
    return out


def plan_options(history: ScenarioBatch, values: np.ndarray, base_goals_xy_m: np.ndarray,
                 prediction: NeighbourPrediction, r_col_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Plans of every option (values (K, 8) or (B, K, 8)) on every scenario in one rollout: positions and
    velocities (B K, F, 2) and adjusted goals (B K, 2), row ``i K + k``."""
    b = len(history)
    v = np.asarray(values, dtype=np.float64)
    v = np.broadcast_to(v, (b, *v.shape)) if v.ndim == 2 else v
    k = v.shape[1]
    rep = np.repeat(np.arange(b), k)
    flat = v.reshape(b * k, -1)
    pred = prediction.take(rep)
    plan = simulate_proposal(history.take(rep), params_of(flat, r_col_m), flat[:, 6], flat[:, 7],
                             np.asarray(base_goals_xy_m, dtype=np.float64)[rep], pred)
    return plan.xy_m, plan.vxy_mps, plan.goals_xy_m


def check_options(history: ScenarioBatch, base_goals_xy_m: np.ndarray, prediction: NeighbourPrediction,
                  table: OptionTable, r_col_m: float, thresholds: ReflectionThresholds | None = None,
                  adverse: AdverseSettings | None = None) -> OptionChecks:
    """Plan and check every option of ``table`` on the B scenarios ``history`` (goals (B, 2) before
    adjustment, predicted neighbours (B, N, F, ...))."""
    th = thresholds or ReflectionThresholds()
    settings = adverse or AdverseSettings()
    b, k = len(history), len(table)
    xy, vxy, goals = plan_options(history, table.values, base_goals_xy_m, prediction, r_col_m)
    rep = np.repeat(np.arange(b), k)
    futures = adverse_futures(history, prediction, settings)
    chk = check_futures(history.take(rep), xy, vxy, prediction.take(rep), futures.take(rep))
    ok = chk.predicted_safe(th.ttc_s, th.min_dist_m)
    if th.max_decel_mps2 is not None:
        ok &= peak_braking_mps2(history.ego_vxy_mps[rep, -1, 0], vxy) <= th.max_decel_mps2 + 1e-9
    f = xy.shape[1]
    return OptionChecks(
        names=table.names, adverse_names=tuple(chk.names[1:]), predicted_safe=ok.reshape(b, k),
        adverse_failed=chk.failed(settings).reshape(b, k, -1), progress_m=xy[:, -1, 0].reshape(b, k),
        min_ttc_s=np.minimum(chk.min_ttc_s[:, 0], chk.min_rear_ttc_s[:, 0]).reshape(b, k),
        xy_m=xy.reshape(b, k, f, 2), vxy_mps=vxy.reshape(b, k, f, 2), goals_xy_m=goals.reshape(b, k, 2),
    )


def preference_order(passes_all: np.ndarray, progress_m: np.ndarray,
                     changes_lane: np.ndarray | None = None) -> list[int]:
    """One scenario's options that pass every check (``passes_all`` (K,)), most progress (``progress_m``
    (K,)) first: the order the shield tries presets in. ``changes_lane`` (K,) bool: those options come after
    every one that keeps the lane (None: no such preference)."""
    ok = np.flatnonzero(passes_all)
    key = -np.nan_to_num(progress_m[ok], nan=-1e3)
    if changes_lane is not None:
        key = key + LANE_CHANGE_PENALTY * np.asarray(changes_lane, dtype=bool)[ok]
    return [int(k) for k in ok[np.argsort(key, kind="stable")]]


#: ranks an option that changes lane behind every option failing as few checks that keeps it (progress is
#: at most a few hundred metres; one failed check weighs 1e4)
LANE_CHANGE_PENALTY: Final = 1e3


def rule_choice(predicted_safe: np.ndarray, adverse_failed: np.ndarray, progress_m: np.ndarray,
                changes_lane: np.ndarray | None = None) -> np.ndarray:
    """(B,) the choice without a model: option 0 (the defaults) when it passes every check; else the option
    failing the fewest checks, then (``changes_lane`` (K,) bool given) keeping the lane, then keeping the most
    predicted progress. Inputs (B, K) / (B, K, A)."""
    failed = np.asarray(adverse_failed).sum(axis=2) + ~np.asarray(predicted_safe, dtype=bool)
    key = -failed * 1e4 + np.nan_to_num(np.asarray(progress_m, dtype=np.float64), nan=-1e3)
    if changes_lane is not None:
        key = key - LANE_CHANGE_PENALTY * np.asarray(changes_lane, dtype=bool)[None, :]
    best = np.argmax(key, axis=1)
    out: np.ndarray = np.where(failed[:, 0] == 0, 0, best)
    return out


#: the gate's inputs: the history's risk features and the defaults' checks (prediction, each adverse future)
GATE_FEATURE_NAMES: Final[tuple[str, ...]] = (
    *RISK_FEATURE_NAMES, "default_predicted_unsafe", *(f"default_fails_{a}" for a in ADVERSE_FUTURES))


def gate_features(history: ScenarioBatch, predicted_safe: np.ndarray, adverse_failed: np.ndarray,
                  adverse_names: Sequence[str]) -> np.ndarray:
    """(B, len(GATE_FEATURE_NAMES)): risk features plus the defaults' check results (predicted_safe (B,),
    adverse_failed (B, A) for the futures ``adverse_names``; a future not checked counts as passed)."""
    failed = np.zeros((len(history), len(ADVERSE_FUTURES)))
    for a, name in enumerate(adverse_names):
        failed[:, ADVERSE_FUTURES.index(AdverseFuture(name))] = adverse_failed[:, a]
    unsafe = (~np.asarray(predicted_safe, dtype=bool))[:, None].astype(np.float64)
    return np.concatenate([risk_features(history), unsafe, failed], axis=1)


class ScoreModel(Protocol):
    """A binary classifier with NumPy inference (``LogisticModel``, ``TreeEnsemble``)."""

    @property
    def feature_names(self) -> tuple[str, ...]: ...

    @property
    def provenance(self) -> dict[str, Any]: ...

    def score(self, x: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class RiskGate:
    """The risk score (P(the defaults collide)) and the gate: consult the model only where the score is at
    least ``threshold`` (None: everywhere)."""

    model: ScoreModel
    threshold: float | None

    def __post_init__(self) -> None:
        if tuple(self.model.feature_names) != GATE_FEATURE_NAMES:
            raise ValueError(f"the risk model's features {self.model.feature_names} are not the gate's "
                             f"{GATE_FEATURE_NAMES}")

    def scores(self, history: ScenarioBatch, checks: OptionChecks) -> np.ndarray:
        """(B,) risk scores in [0, 1] (from the defaults' checks, option 0)."""
        return self.model.score(gate_features(history, checks.predicted_safe[:, 0], checks.adverse_failed[:, 0],
                                              checks.adverse_names))


def recommended_threshold(path: Path | None = None) -> float:
    """The gate threshold the risk model was shipped with (``provenance.threshold``)."""
    model, _ = load_risk_model(path)
    try:
        return float(model.provenance["threshold"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path or 'the shipped risk model'}: no recommended threshold in its provenance; "
                         "give --gate-threshold") from exc


def load_risk_model(path: Path | None = None) -> tuple[ScoreModel, str]:
    """The gate's model (shipped, or ``path``: trees or a logistic model, by its ``format``) and its SHA-256."""
    text, where = _data_text(RISK_MODEL_FILE) if path is None else (Path(path).read_text(), str(path))
    data = json.loads(text)
    model: ScoreModel = (TreeEnsemble.from_json(data, where) if data.get("format") == TREES_FORMAT
                         else LogisticModel.from_json(data, where))
    return model, hashlib.sha256(text.encode()).hexdigest()


#: the decision of a model's own eight numbers (not a preset)
CUSTOM: Final = "custom"


@dataclass(frozen=True)
class GatedChecks:
    """The checks the no-model rule needs, B scenarios: every preset's where ``complete`` (B,), else only the
    defaults' (other entries: unsafe, failing every future, NaN plans); ``risk`` and ``consulted`` (B,)."""

    checks: OptionChecks
    complete: np.ndarray
    risk: np.ndarray
    consulted: np.ndarray
    changes_lane: np.ndarray | None = None  # (K,) the rule's lane preference (``Decider.lane_changes``)

    def rule(self) -> np.ndarray:
        """(B,) the rule's choice where the gate consults (the defaults elsewhere)."""
        return np.where(self.consulted, rule_choice(self.checks.predicted_safe, self.checks.adverse_failed,
                                                    self.checks.progress_m, self.changes_lane), 0)


def _merge_rows(partial: OptionChecks, names: tuple[str, ...], rows: np.ndarray,
                full: OptionChecks | None) -> OptionChecks:
    """``partial`` (the defaults only) widened to the K options ``names``, with ``full``'s checks in ``rows``."""
    b, k = partial.predicted_safe.shape[0], len(names)
    out: dict[str, np.ndarray] = {}
    fills = {"predicted_safe": False, "adverse_failed": True}  # unknown: not safe, failing every future
    for name in OptionChecks.ARRAYS:
        fill = fills.get(name, np.nan)
        part = getattr(partial, name)
        arr = np.full((b, k, *part.shape[2:]), fill, dtype=part.dtype)
        arr[:, :1] = part
        if full is not None:
            arr[rows] = getattr(full, name)
        out[name] = arr
    return OptionChecks(names=names, adverse_names=partial.adverse_names, **out)


@dataclass(frozen=True)
class Decider:
    """The decision step as the phases use it. ``adverse`` None: the prediction only (an ablation); ``gate``
    None or without threshold: consult everywhere; ``verify``: the fast phase applies ``verified``; ``keep_lane``:
    the rule and the shield take a lane-changing preset only where every lane keeper fails more checks;
    ``idm_fallback``: where no alternative passes the shield's checks, it tries an IDM plan too."""

    presets: OptionTable
    r_col_m: float
    thresholds: ReflectionThresholds
    adverse: AdverseSettings | None
    gate: RiskGate | None
    verify: bool = False
    keep_lane: bool = False
    idm_fallback: bool = False

    @property
    def adverse_settings(self) -> AdverseSettings:
        return self.adverse if self.adverse is not None else AdverseSettings(futures=())

    @property
    def lane_changes(self) -> np.ndarray | None:
        """(K,) bool: presets moving the goal to another lane, ranked behind lane keepers (None: no ``keep_lane``)."""
        if not self.keep_lane:
            return None
        out: np.ndarray = np.abs(self.presets.values[:, 7] - NEUTRAL_LANE_FACTOR) > 1e-9
        return out

    def check(self, history: ScenarioBatch, base_goals_xy_m: np.ndarray,
              prediction: NeighbourPrediction) -> OptionChecks:
        """Every preset planned and checked on the B scenarios ``history``."""
        return check_options(history, base_goals_xy_m, prediction, self.presets, self.r_col_m, self.thresholds,
                             self.adverse_settings)

    def gated_checks(self, history: ScenarioBatch, base_goals_xy_m: np.ndarray,
                     prediction: NeighbourPrediction) -> GatedChecks:
        """What the rule needs, checked lazily: the defaults everywhere, every preset only where the gate
        consults and the defaults fail (elsewhere the rule keeps them). Same choices as ``rule`` over ``check``."""
        defaults = check_options(history, base_goals_xy_m, prediction, self.presets.subset([0]), self.r_col_m,
                                 self.thresholds, self.adverse_settings)
        risk = self.risk_scores(history, defaults)
        consulted = self.consulted(risk)
        rows = np.flatnonzero(consulted & ~defaults.passes_all()[:, 0])
        full = self.check(history.take(rows), np.asarray(base_goals_xy_m)[rows],
                          prediction.take(rows)) if rows.size else None
        complete = np.zeros(len(history), dtype=bool)
        complete[rows] = True
        return GatedChecks(_merge_rows(defaults, self.presets.names, rows, full), complete, risk, consulted,
                           self.lane_changes)

    def risk_scores(self, history: ScenarioBatch, checks: OptionChecks) -> np.ndarray:
        """(B,) the gate's scores; NaN without a gate."""
        if self.gate is None:
            return np.full(len(history), np.nan)
        return self.gate.scores(history, checks)

    def consulted(self, risk_scores: np.ndarray) -> np.ndarray:
        """(B,) whether the model is asked (always without a gate or its threshold)."""
        if self.gate is None or self.gate.threshold is None:
            return np.ones(len(risk_scores), dtype=bool)
        out: np.ndarray = np.asarray(risk_scores) >= self.gate.threshold
        return out

    def rule(self, checks: OptionChecks) -> np.ndarray:
        """(B,) the no-model choice (``rule_choice``) as preset indices."""
        return rule_choice(checks.predicted_safe, checks.adverse_failed, checks.progress_m, self.lane_changes)

    def verified(self, checks: OptionChecks, option: str) -> str:
        """Scenario 0's option after verification: the model's ``option`` unless a preset fails fewer checks,
        then the rule's choice (the model keeps the say among equally checked options; with ``keep_lane`` not for a
        lane change where a preset keeping the lane fails no more checks)."""
        if option not in checks.names:
            return option
        failed = checks.failed_checks()[0]
        k = checks.names.index(option)
        lanes = self.lane_changes
        if lanes is not None and lanes[k] and (failed[~lanes] <= failed[k]).any():
            return checks.names[int(self.rule(checks)[0])]  # a lane keeper is as safe: no lane change
        if failed[k] <= failed.min():
            return option
        return checks.names[int(self.rule(checks)[0])]
