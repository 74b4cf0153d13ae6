"""How often the embedded choice model answers its label on the validation examples of its training data.

Usage: python scripts/choice_model_accuracy.py LABELS_DIR [LABELS_DIR ...]

The labels directories are those `letspi train decide` wrote (`OUT/labels/NAME`) and `letspi train llm`
trained on, given in the same order; the validation examples are the ones `letspi train llm` held out (by
ego vehicle, 10 %, seed 0). Each distinct prompt is asked once through the default model spec
(`llamacpp:smollm2-135m-letspi`; set LETSPI_LLM_ADAPTER to try another adapter), uncached. Prints the
accuracy overall and per label (all examples, and first proposals only), the answers' shares in first
proposals, the confusion (kind, label -> answer) and the median latency per call as JSON.

It also scores each answer by the window's hindsight (the labels' ``hindsight_json``: per preset the at-fault
contact, contact and success of its plan against the recorded future): per kind and label, how many answers had
the label's outcome (``same_outcome``), a better one (``better``) or a worse one (``worse``), and how often the
label itself was the best preset in hindsight (``label_best``; ``letspi_train.finetune.preference``'s utility,
an outcome worth 1 or more, progress breaking ties). A wrong answer with the label's outcome costs nothing
in that window; one with a worse outcome does.
"""

from __future__ import annotations

import collections
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from letspi.assembly.build import Builder
from letspi.assembly.resolve import goals_config
from letspi.llm.client import ParamAdvisor
from letspi.method.decide import load_presets
from letspi_train.finetune.data import build_examples_many, read_choice_labels, split_examples
from letspi_train.finetune.decide_data import HINDSIGHT_COLUMN
from letspi_train.finetune.preference import hindsight_utility, hindsight_verdict


def main(dirs: list[Path]) -> dict[str, object]:
    goal_predictor = Builder(cache=None).goal_predictor(goals_config("learned"))
    examples, _ = build_examples_many(dirs, goal_predictor)
    _, val = split_examples(examples, 0.1, 0)
    names = list(load_presets()[0].names)
    options: dict[str, Any] = {n: n for n in names}  # only the chosen name is read
    advisor = ParamAdvisor("llamacpp:smollm2-135m-letspi", cache=None)
    hindsight, weights = hindsight_of_windows(dirs, names)
    confusion: collections.Counter[tuple[str, str, str]] = collections.Counter()
    versus: dict[tuple[str, str], collections.Counter[str]] = collections.defaultdict(collections.Counter)
    latencies: list[float] = []
    seen: set[tuple[str, str]] = set()
    for example in val:
        key = (json.dumps(list(map(dict, example.messages)), sort_keys=True), example.reply)
        if key in seen:  # weighted examples repeat: ask each prompt once
            continue
        seen.add(key)
        started = time.perf_counter()
        advice = advisor.choose(list(example.messages), options)
        latencies.append(time.perf_counter() - started)
        label = json.loads(example.reply)["option"]
        confusion[(example.kind, label, str(advice.choice))] += 1
        verdicts = compare_in_hindsight(hindsight[example.scenario_digest], names, weights, label, str(advice.choice))
        versus[(example.kind, label)].update(verdicts)
    n = sum(confusion.values())
    return {"n": n, "accuracy": sum(v for k, v in confusion.items() if k[1] == k[2]) / max(n, 1),
            "median_latency_s": sorted(latencies)[len(latencies) // 2] if latencies else None,
            "per_label": per_label(confusion), "per_label_propose": per_label(confusion, "propose"),
            "answers_propose": answer_shares(confusion, "propose"),
            "hindsight": {f"{kind} {label}": dict(sorted(c.items())) for (kind, label), c in sorted(versus.items())},
            "confusion": {f"{kind} {label} -> {answer}": v for (kind, label, answer), v in sorted(confusion.items())}}


def hindsight_of_windows(dirs: list[Path], names: list[str]) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """Per window (scenario digest) its presets' (K, 4) hindsight ``[at_fault, contact, success, progress_m]``,
    rows in the order of ``names``, and the labels' utility weights; ``ValueError`` naming the directory whose
    labels lack the column or were made for other presets."""
    out: dict[str, np.ndarray] = {}
    weights: dict[str, float] = {}
    for d in dirs:
        df, manifest = read_choice_labels(d)
        if HINDSIGHT_COLUMN not in df.columns:
            raise ValueError(f"{d}: the labels have no {HINDSIGHT_COLUMN} column (rebuild them with `letspi train "
                             "decide`)")
        if list(manifest["presets"]) != names:
            raise ValueError(f"{d}: labels for the presets {manifest['presets']}, not the shipped {names}")
        weights = dict(manifest["weights"])
        for digest, text in zip(df["scenario_digest"], df[HINDSIGHT_COLUMN], strict=True):
            out[str(digest)] = np.asarray(json.loads(text), dtype=np.float64)
    return out, weights


def compare_in_hindsight(h: np.ndarray, names: list[str], weights: dict[str, float], label: str,
                         answer: str) -> list[str]:
    """The answer against the label in one window's hindsight ``h`` (K, 4) (``hindsight_verdict``), and
    ``label_best`` when no preset beats the label's utility by an outcome (1 or more)."""
    i, j = names.index(label), names.index(answer)
    u = hindsight_utility(h, weights)
    return [hindsight_verdict(h, weights, i, j), *(["label_best"] if u.max() - u[i] < 1.0 else [])]


def per_label(confusion: collections.Counter[tuple[str, str, str]], kind: str | None = None) -> dict[str, object]:
    """Per label (of the examples of ``kind``, all without): how many, how many answered right, the share."""
    out: dict[str, object] = {}
    for label in sorted({k[1] for k in confusion}):
        rows = {k: v for k, v in confusion.items() if k[1] == label and (kind is None or k[0] == kind)}
        n = sum(rows.values())
        if n:
            right = sum(v for k, v in rows.items() if k[2] == label)
            out[label] = {"n": n, "right": right, "accuracy": right / n}
    return out


def answer_shares(confusion: collections.Counter[tuple[str, str, str]], kind: str) -> dict[str, float]:
    """How often each answer was given to the examples of ``kind``."""
    rows = {k: v for k, v in confusion.items() if k[0] == kind}
    n = max(sum(rows.values()), 1)
    shares: dict[str, float] = {}
    for (_, _, answer), v in rows.items():
        shares[answer] = shares.get(answer, 0.0) + v / n
    return dict(sorted(shares.items()))


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    print(json.dumps(main([Path(a) for a in sys.argv[1:]]), indent=1))
