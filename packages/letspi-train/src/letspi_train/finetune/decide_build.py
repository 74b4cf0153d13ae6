"""``letspi train decide``: runs ``letspi_train.finetune.decide_data``'s steps over scenario files and writes the
presets, risk gate and choice labels with their provenance."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from letspi.analysis.options import OptionOutcomes, OptionRun
from letspi.fsutil import atomic_write_text, provenance_path
from letspi.learned.trees import TreeEnsemble
from letspi.method.choosers import TEACHER_FILE
from letspi.method.decide import PRESETS_FORMAT, OptionTable, defaults_vector, gate_features, load_presets
from letspi.physics.goals import GoalPredictor
from letspi.physics.params import SocialForceParams
from letspi.safety.adverse import AdverseSettings
from letspi.scenario.identity import dataset_digest, scenario_digests
from letspi.scenario.split import vehicle_keys
from letspi.scenario.store import load_scenarios
from letspi_train.finetune.decide_data import (
    CHOICE_FORMAT,
    Weights,
    choice_labels,
    expected_utility,
    fit_gate,
    fit_teacher,
    grouped_fold,
    label_frame,
    outcome_probabilities,
    pool_option_table,
    select_presets,
)
from letspi_train.finetune.labels import LABELS_FILE, MANIFEST_FILE, _write_parquet


def _given_presets(pool: OptionTable, given: OptionTable, params: SocialForceParams) -> list[int]:
    """The pool indices of the ``given`` presets (each a pool option by name and value; the defaults
    ``params``')."""
    chosen = []
    for k, name in enumerate(given.names):
        if name not in pool.names:
            raise ValueError(f"preset {name!r} is not an option of the pool ({', '.join(pool.names)})")
        j = pool.names.index(name)
        expected = defaults_vector(params) if k == 0 else pool.values[j]
        if not np.allclose(given.values[k], expected, rtol=0, atol=1e-9):
            raise ValueError(f"preset {name!r} has other values than the pool's option of that name")
        chosen.append(j)
    return chosen


def _write_presets(out: Path, pool: OptionTable, everything: OptionOutcomes, n_presets: int,
                   params: SocialForceParams, presets_file: Path | None,
                   provenance: dict[str, Any]) -> tuple[list[int], OptionTable]:
    """The presets (selected from the pool, or ``presets_file``'s) as pool indices and as a table, written to
    ``out/presets.json``."""
    if presets_file is None:
        chosen = sorted(select_presets(everything, n_presets))  # in the pool's order: the defaults, then by caution
    else:
        chosen = _given_presets(pool, load_presets(presets_file)[0], params)
    presets = OptionTable(tuple(pool.names[k] for k in chosen), pool.values[chosen])
    if presets_file is None:
        atomic_write_text(out / "presets.json", json.dumps({"format": PRESETS_FORMAT, **presets.to_json(),
                                                            "provenance": provenance}, indent=1) + "\n")
    else:
        atomic_write_text(out / "presets.json", Path(presets_file).read_text())
    return chosen, presets


def _write_gate(out: Path, features: np.ndarray, everything: OptionOutcomes, fold: np.ndarray, consult_share: float,
                risk_model_file: Path | None, provenance: dict[str, Any]) -> tuple[TreeEnsemble, np.ndarray]:
    """The gate (fitted, or ``risk_model_file``'s) and its (B,) scores of the windows, written to
    ``out/risk_model.json``: cross-validated scores of a fitted gate, the given gate's own otherwise."""
    if risk_model_file is None:
        gate, risk = fit_gate(features, everything, fold, consult_share=consult_share, provenance=provenance)
        atomic_write_text(out / "risk_model.json", json.dumps(gate.to_json()) + "\n")
    else:
        gate = TreeEnsemble.load(risk_model_file)
        risk = gate.score(features)
        atomic_write_text(out / "risk_model.json", Path(risk_model_file).read_text())
    return gate, risk


def build_decision_data(scenario_files: Sequence[Path], out: Path, goal_predictor: GoalPredictor,
                        params: SocialForceParams, *, goals: str, n_presets: int, consult_share: float,
                        keep_share: float, refine_weight: float, weights: Weights | None = None, command: str = "",
                        progress: Callable[[int], None] | None = None, presets_file: Path | None = None,
                        risk_model_file: Path | None = None) -> dict[str, Any]:
    """Every step of ``letspi train decide``; returns a summary (also in the manifests).

    ``presets_file`` / ``risk_model_file``: keep these presets and this gate (copied to ``out``; the gate's
    scores and recommended threshold stand in for the cross-validated ones) instead of selecting and fitting
    them: labels and teacher for a shipped decision step."""
    out = Path(out)
    weights = weights or Weights()
    pool = pool_option_table(params)
    adverse = AdverseSettings()
    outcomes, batches = [], []
    for path in scenario_files:
        batch = load_scenarios(path)
        run = OptionRun.create(batch, pool, out / "pool" / Path(path).stem, goal_predictor, params, goals=goals,
                               checks=True, adverse=adverse)
        outcomes.append(run.run(progress=progress))
        batches.append(batch)
    everything = OptionOutcomes.concat(outcomes)
    sources = [{"file": provenance_path(p), "digest": dataset_digest(scenario_digests(b)), "windows": len(b)}
               for p, b in zip(scenario_files, batches, strict=True)]
    provenance = {"command": command, "sources": sources, "pool": list(pool.names), "goals": goals,
                  "sf_params": params.as_dict(), "adverse": adverse.model_dump(mode="json"),
                  "selection": "greedy cover of the windows where the defaults collide by options that pass every "
                               "plan-time check there and avoid the contact in hindsight"}
    chosen, presets = _write_presets(out, pool, everything, n_presets, params, presets_file, provenance)
    names = tuple(str(a) for a in adverse.futures)
    features = np.concatenate([gate_features(b.history(), o.predicted_safe[:, 0], o.adverse_failed[:, 0], names)
                               for b, o in zip(batches, outcomes, strict=True)])
    groups = np.concatenate([np.char.add(f"{k}/", vehicle_keys(b).astype(str)) for k, b in enumerate(batches)])
    fold = grouped_fold(groups, 5)
    gate, risk = _write_gate(out, features, everything, fold, consult_share, risk_model_file,
                             {"command": command, "sources": sources, "consult_share_requested": consult_share})
    preset_outcomes = everything.take_options(chosen)
    checks = np.concatenate([preset_outcomes.predicted_safe, preset_outcomes.adverse_failed.reshape(len(fold), -1),
                             preset_outcomes.progress_m - preset_outcomes.progress_m[:, :1]], axis=1).astype(np.float64)
    x = np.concatenate([features, risk[:, None], checks], axis=1)
    probabilities = outcome_probabilities(x, preset_outcomes, fold)
    eu = expected_utility(probabilities, preset_outcomes, weights)
    teacher = fit_teacher(x, preset_outcomes, presets.names, names, weights,
                          {"command": command, "sources": sources, "presets_sha256": presets.sha256(),
                           "risk_model": "fitted here" if risk_model_file is None else provenance_path(risk_model_file),
                           "windows": len(x)})
    atomic_write_text(out / TEACHER_FILE, json.dumps(teacher.to_json()) + "\n")
    consulted = risk >= float(gate.provenance["threshold"])
    labels = choice_labels(eu, risk, consulted, preset_outcomes, keep_share=keep_share, refine_weight=refine_weight)
    starts = np.cumsum([0, *(len(b) for b in batches)])
    shares: dict[str, int] = {}
    n_examples = 0
    for f, (path, batch) in enumerate(zip(scenario_files, batches, strict=True)):
        lo, hi = int(starts[f]), int(starts[f + 1])
        own = [replace(lab, row=lab.row - lo) for lab in labels if lo <= lab.row < hi]
        frame = label_frame(own, preset_outcomes.take(np.arange(lo, hi)), presets, names,
                            [str(d) for d in scenario_digests(batch)])
        directory = out / "labels" / Path(path).stem
        directory.mkdir(parents=True, exist_ok=True)
        _write_parquet(directory / LABELS_FILE, frame)
        manifest = {"format": CHOICE_FORMAT, "scenarios_path": str(path), "presets": list(presets.names),
                    "presets_sha256": presets.sha256(), "weights": asdict(weights), "keep_share": keep_share,
                    "refine_weight": refine_weight, "n_rows": len(frame), "command": command,
                    "dataset_digest": dataset_digest(scenario_digests(batch))}
        atomic_write_text(directory / MANIFEST_FILE, json.dumps(manifest, indent=2) + "\n")
        n_examples += len(frame)
        for name, n in frame["option"].value_counts().items():
            shares[str(name)] = shares.get(str(name), 0) + int(n)
    return {"presets": list(presets.names), "gate": gate.provenance, "n_examples": n_examples,
            "label_shares": shares}
