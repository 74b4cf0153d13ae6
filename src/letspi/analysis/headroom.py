"""How much could any choice of the LLM's eight numbers gain on a set of windows? (``letspi analyze headroom``)

Each row is a chooser picking one option (``letspi.analysis.options``) per window, all scored on the same windows
against the recorded future: ``defaults`` (``sf``), ``best constant``, the hindsight oracles (the bound of any
chooser), the no-model ``rule`` and a ``history chooser (CV)``; the risk AUCs say how well history and the checks
predict the defaults' at-fault collisions."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from letspi.analysis.options import OptionOutcomes
from letspi.learned.logistic_fit import fit_logistic, roc_auc
from letspi.method.decide import DEFAULT_NAME, OptionTable, rule_choice
from letspi.metrics.stats import paired_rate, wilson_interval
from letspi.scenario.risk_features import RISK_FEATURE_NAMES

#: weights of ``hindsight_utility``: at-fault contact, then any contact, then success; progress [m] breaks ties
W_AT_FAULT, W_COLLISION, W_SUCCESS, W_PROGRESS_PER_M = 4.0, 2.0, 1.0, 1e-3


def hindsight_utility(o: OptionOutcomes) -> np.ndarray:
    """(B, C) how good each option turned out, higher is better (weights above)."""
    u: np.ndarray = (-W_AT_FAULT * o.at_fault - W_COLLISION * o.collision + W_SUCCESS * o.success
                     + W_PROGRESS_PER_M * np.nan_to_num(o.progress_m))
    return u


def good_in_hindsight(o: OptionOutcomes) -> np.ndarray:
    """(B, C): no contact and success."""
    out: np.ndarray = ~o.collision & o.success
    return out


def hindsight_label(o: OptionOutcomes, options: Sequence[int] | np.ndarray) -> np.ndarray:
    """(B,) the option (an index into the table) to learn: the defaults (option 0) when they were good
    in hindsight, else the best of ``options`` by ``hindsight_utility``."""
    cols = np.asarray(options, dtype=np.int64)
    u = hindsight_utility(o)[:, cols]
    best = cols[np.argmax(u, axis=1)]
    out: np.ndarray = np.where(good_in_hindsight(o)[:, 0], 0, best)
    return out


@dataclass(frozen=True)
class Choice:
    """One chooser's pick per window: name, what it is, choice (B,) option indices."""

    name: str
    description: str
    choice: np.ndarray


def oracle(o: OptionOutcomes, options: Sequence[int]) -> np.ndarray:
    """(B,) the hindsight-best of ``options`` per window (ties: the earliest, so the defaults first)."""
    cols = np.asarray(options, dtype=np.int64)
    out: np.ndarray = cols[np.argmax(hindsight_utility(o)[:, cols], axis=1)]
    return out


def best_constant(o: OptionOutcomes) -> int:
    """The option with the fewest at-fault contacts over all windows (ties: more successes, then progress)."""
    key = np.lexsort((np.nanmean(o.progress_m, axis=0), o.success.mean(axis=0), -o.at_fault.mean(axis=0)))
    return int(key[-1])


def rule_over(o: OptionOutcomes, presets: Sequence[int]) -> np.ndarray:
    """(B,) the no-model rule (``letspi.method.decide.rule_choice``) over ``presets`` (option indices; needs checks)."""
    cols = np.asarray(presets, dtype=np.int64)
    if cols[0] != 0:
        raise ValueError("the presets must start with the defaults (option 0)")
    out: np.ndarray = cols[rule_choice(o.predicted_safe[:, cols], o.adverse_failed[:, cols], o.progress_m[:, cols])]
    return out


def grouped_folds(groups: np.ndarray, folds: int, seed: int = 0) -> np.ndarray:
    """(B,) fold index per window; all windows of one group (ego vehicle) share a fold."""
    uniq, inverse = np.unique(np.asarray(groups).astype(str), return_inverse=True)
    perm = np.random.default_rng(seed).permutation(len(uniq))
    out: np.ndarray = (perm % folds)[inverse]
    return out


def cross_validated(fit_predict: Callable[[np.ndarray, np.ndarray], np.ndarray], fold: np.ndarray) -> np.ndarray:
    """Predictions for every window by the model fitted on the other folds (``fit_predict(train, test)``)."""
    out: np.ndarray | None = None
    for f in np.unique(fold):
        test, train = fold == f, fold != f
        pred = np.asarray(fit_predict(np.flatnonzero(train), np.flatnonzero(test)))
        if out is None:
            out = np.zeros((len(fold), *pred.shape[1:]), dtype=pred.dtype)
        out[test] = pred
    assert out is not None
    return out


def history_chooser(o: OptionOutcomes, presets: Sequence[int], features: np.ndarray, fold: np.ndarray,
                    l2: float = 1.0) -> np.ndarray:
    """(B,) presets chosen from history features by grouped cross-validation (module docstring)."""
    cols = np.asarray(presets, dtype=np.int64)
    label = hindsight_label(o, cols)
    index_of = {int(c): k for k, c in enumerate(cols)}
    y = np.array([index_of[int(v)] for v in label])
    names = tuple(str(c) for c in cols)

    def fit_predict(train: np.ndarray, test: np.ndarray) -> np.ndarray:
        present = np.unique(y[train])
        if len(present) <= 1:  # one class to learn (or no training window): that class, else the defaults
            return np.full(len(test), cols[present[0]] if len(present) else 0)
        remap = {int(c): k for k, c in enumerate(present)}
        model = fit_logistic(features[train], np.array([remap[int(v)] for v in y[train]]),
                             classes=tuple(names[p] for p in present), feature_names=RISK_FEATURE_NAMES, l2=l2)
        return cols[present[model.predict(features[test])]]

    return cross_validated(fit_predict, fold)


def risk_aucs(o: OptionOutcomes, features: np.ndarray, fold: np.ndarray) -> dict[str, float]:
    """AUC of predicting "the defaults collide at fault" from history (grouped CV) and, with plan-time
    checks, from "the defaults fail an adverse future"."""
    positive = o.at_fault[:, 0]
    y = positive.astype(np.int64)

    def fit_predict(train: np.ndarray, test: np.ndarray) -> np.ndarray:
        if len(np.unique(y[train])) < 2:
            return np.zeros(len(test))
        model = fit_logistic(features[train], y[train], classes=("safe", "at_fault"), feature_names=RISK_FEATURE_NAMES)
        return model.score(features[test])

    out = {"history_cv": roc_auc(cross_validated(fit_predict, fold), positive)}
    if o.adverse_failed.shape[2]:
        out["defaults_fail_adverse"] = roc_auc(o.adverse_failed[:, 0].sum(axis=1).astype(np.float64), positive)
    out["n_positive"] = float(positive.sum())
    return out


def headroom_choices(o: OptionOutcomes, table: OptionTable, presets: Sequence[int], features: np.ndarray,
                     groups: np.ndarray, *, folds: int = 5, seed: int = 0) -> list[Choice]:
    """Every chooser of the module docstring on the same windows (the rule only with plan-time checks)."""
    if table.names[0] != DEFAULT_NAME:
        raise ValueError(f"option 0 must be the defaults ({DEFAULT_NAME!r}), got {table.names[0]!r}")
    b = len(o)
    everything = list(range(len(table)))
    const = best_constant(o)
    fold = grouped_folds(groups, folds, seed)
    out = [
        Choice("defaults", "the fitted sf parameters everywhere", np.zeros(b, dtype=np.int64)),
        Choice("best constant", f"one option everywhere ({table.names[const]}: fewest at-fault contacts)",
               np.full(b, const)),
        Choice("oracle, all options", f"best of all {len(table)} options per window, in hindsight",
               oracle(o, everything)),
        Choice("oracle, presets", f"best of the {len(presets)} presets per window, in hindsight", oracle(o, presets)),
    ]
    if o.adverse_failed.shape[2]:
        out.append(Choice("rule: defaults unless a check fails",
                          "defaults when they pass the predicted and adverse checks, else the preset passing most",
                          rule_over(o, presets)))
    out.append(Choice("history chooser (CV)",
                      f"logistic regression on {features.shape[1]} history features -> preset, {folds}-fold by vehicle",
                      history_chooser(o, presets, features, fold)))
    return out


@dataclass(frozen=True)
class HeadroomResult:
    """The table (one row per chooser) and the risk AUCs of one scenario file."""

    rows: list[dict[str, Any]]
    risk: dict[str, float]
    n_windows: int

    def to_json(self) -> dict[str, Any]:
        return {"rows": self.rows, "risk_auc": self.risk, "n_windows": self.n_windows}

    def to_markdown(self) -> str:
        head = ("| chooser | CR % [95 % CI] | CR at fault % [95 % CI] | SR % | progress m | changed % | "
                "at fault vs defaults: only chooser / only defaults, McNemar p |")
        lines = [head, "|---|---:|---:|---:|---:|---:|---:|"]
        for r in self.rows:
            cr, fault = r["collision_pct"], r["at_fault_pct"]
            lines.append(
                f"| {r['name']} | {cr:.2f} [{r['collision_ci95'][0]:.2f}, {r['collision_ci95'][1]:.2f}] | "
                f"{fault:.2f} [{r['at_fault_ci95'][0]:.2f}, {r['at_fault_ci95'][1]:.2f}] | {r['success_pct']:.2f} | "
                f"{r['progress_m']:.1f} | {r['changed_pct']:.1f} | {r['vs_defaults_only_chooser']} / "
                f"{r['vs_defaults_only_defaults']}, p = {r['vs_defaults_p_mcnemar']:.2g} |")
        risk = ", ".join(f"{k} {v:.3f}" for k, v in self.risk.items() if not k.startswith("n_positive"))
        lines += ["", f"{self.n_windows} windows; risk AUC (defaults collide at fault, "
                      f"{int(self.risk.get('n_positive', 0))} windows): {risk}"]
        return "\n".join(lines)


def _pct_interval(flags: np.ndarray) -> list[float]:
    return [100 * x for x in wilson_interval(int(flags.sum()), len(flags))]


def headroom(o: OptionOutcomes, table: OptionTable, presets: Sequence[int], features: np.ndarray,
             groups: np.ndarray, *, folds: int = 5, seed: int = 0, gate_scores: np.ndarray | None = None,
             ) -> HeadroomResult:
    """Every chooser's rates on the same windows, Wilson intervals, at-fault McNemar counts against the defaults."""
    rows_idx = np.arange(len(o))
    base_fault = o.at_fault[:, 0]
    rows = []
    for c in headroom_choices(o, table, presets, features, groups, folds=folds, seed=seed):
        coll, fault = o.collision[rows_idx, c.choice], o.at_fault[rows_idx, c.choice]
        paired = paired_rate(fault, base_fault, groups)
        rows.append({
            "name": c.name, "description": c.description,
            "collision_pct": 100 * coll.mean(), "collision_ci95": _pct_interval(coll),
            "at_fault_pct": 100 * fault.mean(), "at_fault_ci95": _pct_interval(fault),
            "success_pct": 100 * o.success[rows_idx, c.choice].mean(),
            "progress_m": float(np.nanmean(o.progress_m[rows_idx, c.choice])),
            "changed_pct": 100 * float(np.mean(c.choice != 0)),
            "decisions": {table.names[k]: int(v)
                          for k, v in zip(*np.unique(c.choice, return_counts=True), strict=True)},
            "vs_defaults_only_chooser": paired.n_only_a, "vs_defaults_only_defaults": paired.n_only_b,
            "vs_defaults_p_mcnemar": paired.p_mcnemar,
        })
    risk = risk_aucs(o, features, grouped_folds(groups, folds, seed))
    if gate_scores is not None:  # the shipped risk model, trained on other traffic: its target is any contact
        risk["shipped_gate_any_contact"] = roc_auc(gate_scores, o.collision[:, 0])
        risk["n_positive_any_contact"] = float(o.collision[:, 0].sum())
    return HeadroomResult(rows, risk, len(o))
