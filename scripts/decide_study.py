"""Which choosers of the decision step can be learned? A cross-validated study on training traffic.

Reads the option outcomes ``letspi train decide`` cached (``OUT/pool/<file stem>``) for the given
training scenario files and prints, on the same windows (5-fold cross-validation grouped by ego
vehicle), the rates of:

* the defaults; the rule (``letspi.method.decide.rule_choice``) over the presets, everywhere;
* the risk gate (trees on the gate features, cross-validated) with a fixed preset where it fires;
* a classifier trained on "the best preset in hindsight" (the labels that teach the mode);
* the expected-utility policy inside the gate (the decision-focused labels ``letspi train decide``
  writes): kept where the defaults were collision-free, changed where they collided, decision shares.

Needs the ``train`` extra (scikit-learn). Usage::

    python scripts/decide_study.py --out td/ --scenarios train200.arrow --scenarios train201.arrow ...
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from letspi.analysis.options import OptionOutcomes, load_option_run
from letspi.method.decide import gate_features, rule_choice
from letspi.safety.adverse import AdverseSettings
from letspi.scenario.split import vehicle_keys
from letspi.scenario.store import load_scenarios
from letspi_train.finetune.decide_data import (
    Weights,
    expected_utility,
    fit_gate,
    grouped_fold,
    outcome_probabilities,
    select_presets,
)


def _row(label: str, o: OptionOutcomes, choice: np.ndarray, names: tuple[str, ...]) -> str:
    r = np.arange(len(o))
    bad = o.collision[:, 0]
    kept = choice == 0
    shares = ", ".join(f"{names[k]} {100 * np.mean(choice == k):.1f}" for k in np.unique(choice))
    return (f"| {label} | {100 * o.collision[r, choice].mean():.2f} | {100 * o.at_fault[r, choice].mean():.2f} | "
            f"{100 * o.success[r, choice].mean():.2f} | {o.progress_m[r, choice].mean():.1f} | "
            f"{100 * kept[~bad].mean():.1f} | {100 * (~kept)[bad].mean():.1f} | {shares} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, required=True, help="the output directory of `letspi train decide`")
    parser.add_argument("--scenarios", type=Path, action="append", required=True)
    parser.add_argument("--presets", type=int, default=6)
    parser.add_argument("--consult-share", type=float, default=0.12)
    args = parser.parse_args()
    from sklearn.ensemble import HistGradientBoostingClassifier

    runs = [load_option_run(args.out / "pool" / p.stem) for p in args.scenarios]
    table = runs[0][0]
    everything = OptionOutcomes.concat([r[1] for r in runs])
    batches = [load_scenarios(p).history() for p in args.scenarios]
    names = tuple(str(a) for a in AdverseSettings().futures)
    features = np.concatenate([gate_features(b, r[1].predicted_safe[:, 0], r[1].adverse_failed[:, 0], names)
                               for b, r in zip(batches, runs, strict=True)])
    groups = np.concatenate([np.char.add(f"{k}/", vehicle_keys(b).astype(str)) for k, b in enumerate(batches)])
    fold = grouped_fold(groups, 5)
    chosen = sorted(select_presets(everything, args.presets))
    o = everything.take_options(chosen)
    preset_names = tuple(table.names[k] for k in chosen)
    _, risk = fit_gate(features, everything, fold, consult_share=args.consult_share)
    gate = risk >= np.quantile(risk, 1.0 - args.consult_share)
    lines = ["| chooser | CR % | CR at fault % | SR % | progress m | kept where safe % | changed where unsafe % | "
             "shares % |", "|---|---:|---:|---:|---:|---:|---:|---|"]
    lines.append(_row("defaults", o, np.zeros(len(o), dtype=np.int64), preset_names))
    lines.append(_row("rule, everywhere", o, rule_choice(o.predicted_safe, o.adverse_failed, o.progress_m),
                      preset_names))
    for k in range(1, len(chosen)):
        lines.append(_row(f"gate -> {preset_names[k]}", o, np.where(gate, k, 0), preset_names))
    checks = np.concatenate([o.predicted_safe, o.adverse_failed.reshape(len(o), -1),
                             o.progress_m - o.progress_m[:, :1]], axis=1).astype(np.float64)
    x = np.concatenate([features, risk[:, None], checks], axis=1)
    # hindsight labels: the defaults where they did not collide, else the best preset in hindsight
    u = -4.0 * o.at_fault - 2.0 * o.collision + o.success + 1e-3 * np.nan_to_num(o.progress_m)
    hindsight = np.where(o.collision[:, 0], np.argmax(u, axis=1), 0)
    for weight in (1.0, 4.0):
        pred = np.zeros(len(o), dtype=np.int64)
        for f in np.unique(fold):
            train, test = fold != f, fold == f
            clf = HistGradientBoostingClassifier(max_iter=150, learning_rate=0.05, random_state=0)
            clf.fit(x[train], hindsight[train], sample_weight=np.where(hindsight[train] != 0, weight, 1.0))
            pred[test] = clf.predict(x[test])
        lines.append(_row(f"classifier on hindsight labels (weight {weight:g} on changes)", o, pred, preset_names))
    eu = expected_utility(outcome_probabilities(x, o, fold), o, Weights())
    best = np.argmax(eu, axis=1)
    policy = np.where(gate & (eu[np.arange(len(o)), best] > eu[:, 0]), best, 0)
    lines.append(_row("expected-utility policy in the gate (the labels)", o, policy, preset_names))
    print(f"{len(o)} windows of {len(args.scenarios)} files; presets {', '.join(preset_names)}; the gate consults "
          f"{100 * gate.mean():.1f} %")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
