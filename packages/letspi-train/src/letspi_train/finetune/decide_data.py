"""Training data of LetsPi's decision step, from training traffic only (``letspi train decide``).

Option outcomes (a pool of candidate answers scored in hindsight and checked at plan time) give: presets,
a greedy cover of the windows where the defaults collide (``select_presets``); the risk gate, P(the defaults
collide) with a threshold that consults a given share of windows (``fit_gate``); and decision-focused
choice labels (``choice_labels``), weighted by risk, with refinement examples where the defaults fail a check.
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import pandas as pd

from letspi.analysis.options import OptionOutcomes
from letspi.learned.logistic_fit import roc_auc
from letspi.learned.trees import TreeEnsemble
from letspi.llm.schema import NUMERIC_FIELDS
from letspi.method.choosers import TEACHER_TARGETS, ConstantScore, OutcomeModel, Teacher, teacher_feature_names
from letspi.method.decide import DEFAULT_NAME, GATE_FEATURE_NAMES, OptionTable, defaults_vector
from letspi.physics.params import SocialForceParams
from letspi_train.finetune.gate_train import fit_trees

#: the hindsight utility's weights (as ``letspi.analysis.headroom``: at-fault contact, contact, success, progress)
_W = (4.0, 2.0, 1.0, 1e-3)


def pool_option_table(params: SocialForceParams) -> OptionTable:
    """The candidate presets: the defaults; nearer goals (``ease``, ``slow``, ``brake``), each also with a
    stronger repulsion from the leader (``-gap``, ``-gap+``; ``keep-gap``); lane changes ``left`` / ``right`` at
    several goals; ``hold`` and ``quick``. Short names: the model writes one in its reply."""
    d = defaults_vector(params)
    field = {f: i for i, f in enumerate(NUMERIC_FIELDS)}
    names, rows = [DEFAULT_NAME], [d.copy()]

    def add(name: str, **values: float) -> None:
        v = d.copy()
        for k, x in values.items():
            v[field[k]] = x
        names.append(name)
        rows.append(v)

    goals = ((0.4, "keep"), (0.55, "ease"), (0.7, "slow"), (1.0, "brake"))
    repulsions = (("", d[1]), ("-gap", 35.0), ("-gap+", 50.0))
    for (lon, word), (gap_name, k_np) in itertools.product(goals, repulsions):
        if lon == 0.4 and not gap_name:
            continue
        add(f"{word}{gap_name}", lon_factor=lon, k_np=k_np)
    for side, lane in (("left", -1.0), ("right", 1.0)):
        for (lon, word), (gap_name, k_np) in itertools.product(((0.4, ""), (0.7, "-slow"), (1.0, "-brake")),
                                                                (("", d[1]), ("-gap", 40.0))):
            add(f"{side}{word}{gap_name}", lane_factor=lane, lon_factor=lon, k_np=k_np)
    add("hold", k_cline=2.0, k_nl=1.5)
    add("quick", tau_s=1.0)
    return OptionTable(tuple(names), np.array(rows))


def utility(o: OptionOutcomes) -> np.ndarray:
    """(B, C) hindsight utility (higher is better)."""
    u: np.ndarray = (-_W[0] * o.at_fault - _W[1] * o.collision + _W[2] * o.success
                     + _W[3] * np.nan_to_num(o.progress_m))
    return u


def select_presets(o: OptionOutcomes, k: int) -> list[int]:
    """K option indices, the defaults first, then greedily the option that fixes (passes every plan-time check,
    no contact in hindsight) the most windows where the defaults collide; ties by success rate."""
    if k < 1:
        raise ValueError("at least one preset (the defaults)")
    bad = o.collision[:, 0]
    fixable = (o.predicted_safe & ~o.adverse_failed.any(axis=2) & ~o.collision)[bad]
    chosen = [0]
    for _ in range(k - 1):
        covered = fixable[:, chosen].any(axis=1)
        gain = (fixable & ~covered[:, None]).sum(axis=0).astype(np.float64) + 1e-3 * o.success.mean(axis=0)
        gain[chosen] = -np.inf
        chosen.append(int(np.argmax(gain)))
    return chosen


def grouped_fold(groups: np.ndarray, folds: int, seed: int = 0) -> np.ndarray:
    """(B,) fold of each window; all windows of one group (ego vehicle) in one fold."""
    uniq, inverse = np.unique(np.asarray(groups).astype(str), return_inverse=True)
    out: np.ndarray = (np.random.default_rng(seed).permutation(len(uniq)) % folds)[inverse]
    return out


def fit_gate(features: np.ndarray, o: OptionOutcomes, fold: np.ndarray, *, consult_share: float,
             provenance: dict[str, Any] | None = None) -> tuple[TreeEnsemble, np.ndarray]:
    """The risk model (gradient-boosted trees, P(the defaults collide) from ``features`` (B, ``GATE_FEATURE_NAMES``))
    and its cross-validated scores (B,); its threshold consults ``consult_share`` of the windows by those
    out-of-fold scores (what a held-out window's score looks like)."""
    positive = o.collision[:, 0]
    oof = np.zeros(len(positive))
    for f in np.unique(fold):
        train, test = fold != f, fold == f
        oof[test] = fit_trees(features[train], positive[train], feature_names=GATE_FEATURE_NAMES).score(features[test])
    threshold = float(np.quantile(oof, 1.0 - consult_share))
    consulted = oof >= threshold
    stats = {"threshold": threshold, "consult_share": float(consulted.mean()), "cv_auc": roc_auc(oof, positive),
             "cv_recall": float(consulted[positive].mean()) if positive.any() else float("nan"),
             "positive_share": float(positive.mean()), "folds": len(np.unique(fold)),
             "target": "the defaults collide in hindsight"}
    model = fit_trees(features, positive, feature_names=GATE_FEATURE_NAMES, provenance={**(provenance or {}), **stats})
    return model, oof


@dataclass(frozen=True)
class ChoiceLabel:
    """One choice example: window ``row``, preset ``label``, ``weight``, prompt ``risk``, ``rejected`` (-1: none)."""

    row: int
    label: int
    weight: float
    risk: float
    rejected: int = -1


@dataclass(frozen=True)
class Weights:
    """The expected utility the labels maximise: ``-at_fault * P(at-fault contact) - contact * P(contact)
    + P(success) + progress_per_m * (progress - the defaults' progress)``."""

    at_fault: float = 8.0
    contact: float = 2.0
    progress_per_m: float = 0.01


#: the outcome trees' settings (``fit_trees``), of the labels' cross-validated estimates and of the teacher
OUTCOME_TREES: dict[str, Any] = {"max_iter": 80, "learning_rate": 0.08, "min_samples_leaf": 30}


def _outcome_model(x: np.ndarray, y: np.ndarray, feature_names: tuple[str, ...]) -> OutcomeModel:
    """One outcome's model: trees, or the constant rate where ``y`` never varies."""
    if y.all() or not y.any():
        return ConstantScore(float(y.mean()))
    return fit_trees(x, y, feature_names=feature_names, **OUTCOME_TREES)


def outcome_probabilities(x: np.ndarray, o: OptionOutcomes, fold: np.ndarray) -> dict[str, np.ndarray]:
    """Cross-validated (B, K) probabilities of each option's at-fault contact, contact and success from the
    plan-time inputs ``x`` (B, D): every window's by the trees fitted on the other folds."""
    out = {name: np.zeros(o.collision.shape) for name in TEACHER_TARGETS}
    names = tuple(f"x{i}" for i in range(x.shape[1]))
    for name in TEACHER_TARGETS:
        target = getattr(o, name)
        for k in range(target.shape[1]):
            for f in np.unique(fold):
                train, test = fold != f, fold == f
                out[name][test, k] = _outcome_model(x[train], target[train, k], names).score(x[test])
    return out


def fit_teacher(x: np.ndarray, o: OptionOutcomes, presets: Sequence[str], adverse_names: Sequence[str],
                weights: Weights, provenance: dict[str, Any] | None = None) -> Teacher:
    """The labels' expected-utility policy as a planner can run it: the outcome trees of
    ``outcome_probabilities`` fitted on all windows (``x`` (B, D): ``teacher_features``; ``o``: the presets'
    outcomes, (B, K))."""
    names = teacher_feature_names(presets, adverse_names)
    if x.shape[1] != len(names):
        raise ValueError(f"the teacher's inputs have {len(names)} columns, got {x.shape[1]}")
    models = {name: tuple(_outcome_model(x, getattr(o, name)[:, k], names) for k in range(len(presets)))
              for name in TEACHER_TARGETS}
    return Teacher(tuple(presets), tuple(adverse_names), {"at_fault": weights.at_fault, "contact": weights.contact,
                                                          "progress_per_m": weights.progress_per_m},
                   models, {**(provenance or {}), "trees": OUTCOME_TREES})


def expected_utility(p: dict[str, np.ndarray], o: OptionOutcomes, w: Weights) -> np.ndarray:
    """(B, K) the expected utility of each option (``Weights``) from ``outcome_probabilities``."""
    progress = np.nan_to_num(o.progress_m)
    eu: np.ndarray = (-w.at_fault * p["at_fault"] - w.contact * p["collision"] + p["success"]
                      + w.progress_per_m * (progress - progress[:, :1]))
    return eu


def choice_labels(eu: np.ndarray, risk: np.ndarray, consulted: np.ndarray, o: OptionOutcomes, *,
                  keep_share: float, refine_weight: float, seed: int = 0) -> list[ChoiceLabel]:
    """Where the gate consults, the option of highest ``eu`` (B, K) if it beats the defaults, else the defaults;
    a ``keep_share`` sample of the other windows keeping the defaults; and a refinement example (rejected:
    the best option, answer: the best passing one) where the best fails a check another passes."""
    rng = np.random.default_rng(seed)
    best = np.argmax(eu, axis=1)
    label = np.where(eu[np.arange(len(eu)), best] > eu[:, 0], best, 0)
    passes = o.predicted_safe & ~o.adverse_failed.any(axis=2)
    out = []
    for i in range(len(eu)):
        if consulted[i]:
            out.append(ChoiceLabel(i, int(label[i]), 1.0, float(risk[i])))
            if not passes[i, label[i]] and passes[i].any():
                others = eu[i] + 1e3 * passes[i]
                others[label[i]] = -np.inf
                out.append(ChoiceLabel(i, int(np.argmax(others)), refine_weight, float(risk[i]), int(label[i])))
        elif rng.random() < keep_share:
            out.append(ChoiceLabel(i, 0, 1.0, float(risk[i])))
    return out


CHOICE_FORMAT = "letspi-choice-labels/1"
CHOICE_COLUMNS: tuple[str, ...] = ("scenario_index", "scenario_digest", "kind", "option", "rejected", "weight",
                                   "risk", "lines_json", "defaults_collide")


def option_lines_of(o: OptionOutcomes, presets: OptionTable, adverse_names: Sequence[str], i: int) -> list[list[Any]]:
    """Window ``i``'s presets as the choice prompt lists them: [name, failed plan-time checks, progress m]."""
    out: list[list[Any]] = []
    for k, name in enumerate(presets.names):
        failed = ([] if o.predicted_safe[i, k] else ["predicted"]) + [
            a for a, bad in zip(adverse_names, o.adverse_failed[i, k], strict=True) if bad]
        out.append([name, failed, float(o.progress_m[i, k])])
    return out


#: an optional column of the choice labels: per preset, the window's hindsight outcome
#: ``[at_fault, contact, success, progress_m]`` (JSON), for preference pairs (``letspi_train.finetune.preference``)
HINDSIGHT_COLUMN: Final = "hindsight_json"


def label_frame(labels: Sequence[ChoiceLabel], o: OptionOutcomes, presets: OptionTable,
                adverse_names: Sequence[str], digests: Sequence[str]) -> pd.DataFrame:
    """The labels as rows (``CHOICE_COLUMNS`` and ``HINDSIGHT_COLUMN``) of one scenario file (``digests`` of
    its windows)."""
    rows = [{"risk": float(lab.risk),
        "scenario_index": lab.row, "scenario_digest": str(digests[lab.row]),
        "kind": "refine" if lab.rejected >= 0 else "propose", "option": presets.names[lab.label],
        "rejected": presets.names[lab.rejected] if lab.rejected >= 0 else "", "weight": float(lab.weight),
        "lines_json": json.dumps(option_lines_of(o, presets, adverse_names, lab.row)),
        "defaults_collide": bool(o.collision[lab.row, 0]),
        HINDSIGHT_COLUMN: json.dumps([[bool(o.at_fault[lab.row, k]), bool(o.collision[lab.row, k]),
                                       bool(o.success[lab.row, k]), float(o.progress_m[lab.row, k])]
                                      for k in range(len(presets))]),
    } for lab in labels]
    return pd.DataFrame(rows, columns=[*CHOICE_COLUMNS, HINDSIGHT_COLUMN])
