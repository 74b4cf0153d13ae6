"""Labels directory (``letspi train llm-data`` or ``letspi train decide``) -> chat examples.

Each label row becomes ``(messages, reply)``: the prompt of its scenario as the planners render it (the
goal they predict included) and the label in the wire format. Rows whose label failed the checks are left
out (the model is only taught answers the physics verified). The train/validation split is by ego vehicle,
so overlapping windows of one vehicle land on one side.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from letspi.llm.choice import OptionLine, choice_check_text, choice_reply_text, render_choice_prompt
from letspi.llm.compact import compact_reply_text, compact_report_text, render_compact_prompt
from letspi.llm.describe import describe_scenario
from letspi.llm.schema import NUMERIC_FIELDS
from letspi.llm.types import Message
from letspi.physics.goals import GoalPredictor
from letspi.scenario.identity import dataset_digest, scenario_digests
from letspi.scenario.split import split_by_key, vehicle_keys
from letspi.scenario.store import load_scenarios
from letspi.scenario.types import ScenarioBatch
from letspi_train.finetune.decide_data import CHOICE_COLUMNS, CHOICE_FORMAT
from letspi_train.finetune.labels import FORMAT, LABELS_FILE, MANIFEST_FILE, load_labels

LABELS_FORMAT = FORMAT
KINDS = ("propose", "refine")


@dataclass(frozen=True)
class ChatExample:
    """One training example: prompt messages, the reply to learn, and where it came from."""

    messages: tuple[Message, ...]
    reply: str
    kind: str
    scenario_digest: str
    #: the scenario's ego vehicle (``letspi.scenario.split.vehicle_keys``): the unit of the split
    vehicle_key: str = ""


def labels_sha256(directory: Path) -> str:
    """SHA-256 of ``labels.parquet`` (the data identity recorded in a training manifest)."""
    h = hashlib.sha256()
    with open(Path(directory) / LABELS_FILE, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def read_labels(directory: Path) -> tuple[pd.DataFrame, dict[str, Any]]:
    """(labels table, manifest) of a labels directory; ``ValueError`` naming the file for unknown kinds."""
    df, manifest = load_labels(directory)
    bad = sorted(set(df["kind"]) - set(KINDS))
    if bad:
        raise ValueError(f"{Path(directory) / LABELS_FILE}: unknown kind(s) {bad}; expected {KINDS}")
    return df, manifest


def _values(row: pd.Series, prefix: str = "") -> dict[str, float]:
    return {f: float(row[prefix + f]) for f in NUMERIC_FIELDS}


def example_of_row(row: pd.Series, desc: Any, vehicle_key: str = "") -> ChatExample:
    """The chat example of one label row, its scenario described by ``desc`` (``ScenarioDescription``)."""
    if row["kind"] == "refine":
        rejected = _values(row, "proposal_")
        if not all(math.isfinite(v) for v in rejected.values()):
            raise ValueError(f"refine row of scenario {row['scenario_digest']}: the rejected proposal has NaN")
        report = json.loads(row["report_json"]) if row["report_json"] else {}
        text = compact_report_text(report, report.get("violations", []))
        messages = render_compact_prompt(desc, rejected=rejected, report=text)
    else:
        messages = render_compact_prompt(desc)
    return ChatExample(tuple(messages), compact_reply_text(_values(row)), str(row["kind"]),
                       str(row["scenario_digest"]), vehicle_key)


def choice_example_of_row(row: pd.Series, desc: Any, vehicle_key: str = "") -> ChatExample:
    """The chat example of one choice label row: the choice prompt over its option lines (a refinement adds
    the rejected preset's failed checks)."""
    lines = [OptionLine(str(name), tuple(failed), float(progress)) for name, failed, progress in
             json.loads(row["lines_json"])]
    rejected = str(row["rejected"]) or None
    report = None
    if rejected is not None:
        failed = next((line.failed for line in lines if line.name == rejected), ())
        report = choice_check_text(failed)
    messages = render_choice_prompt(desc, lines, risk=float(row["risk"]), rejected=rejected, report=report)
    return ChatExample(tuple(messages), choice_reply_text(str(row["option"])), str(row["kind"]),
                       str(row["scenario_digest"]), vehicle_key)


def read_choice_labels(directory: Path) -> tuple[pd.DataFrame, dict[str, Any]]:
    """``labels.parquet`` and ``manifest.json`` of a choice labels directory (``letspi train decide``)."""
    d = Path(directory)
    manifest = json.loads((d / MANIFEST_FILE).read_text())
    if manifest.get("format") != CHOICE_FORMAT:
        raise ValueError(f"{d / MANIFEST_FILE}: format {manifest.get('format')!r}, expected {CHOICE_FORMAT!r}")
    df = pd.read_parquet(d / LABELS_FILE)
    missing = [c for c in CHOICE_COLUMNS if c not in df.columns]
    if missing:
        raise ValueError(f"{d / LABELS_FILE}: missing column(s) {missing}")
    return df, manifest


def _is_choice(directory: Path) -> bool:
    mfile = Path(directory) / MANIFEST_FILE
    return mfile.is_file() and json.loads(mfile.read_text()).get("format") == CHOICE_FORMAT


def build_examples(
    directory: Path,
    goal_predictor: GoalPredictor,
    *,
    scenarios: Path | None = None,
    safe_only: bool = True,
    max_scenarios: int | None = None,
    progress: Callable[[int], None] | None = None,
) -> tuple[list[ChatExample], dict[str, Any]]:
    """Chat examples of a labels directory and a description of the data (for the manifest). ``scenarios``:
    the file the labels index (default: the manifest's; digests must match); ``max_scenarios``: the first N."""
    choice = _is_choice(directory)
    df, manifest = read_choice_labels(directory) if choice else read_labels(directory)
    path = Path(scenarios or manifest.get("scenarios_path", ""))
    if not path.is_file():
        raise FileNotFoundError(f"{directory}/{MANIFEST_FILE}: scenario file {path} not found (pass --scenarios)")
    n_rows = len(df)
    if safe_only and not choice:
        df = df[df["label_safe"].astype(bool)]
    indices = np.unique(df["scenario_index"].to_numpy(dtype=np.int64))
    if max_scenarios is not None:
        indices = indices[:max_scenarios]
        df = df[df["scenario_index"].isin(indices)]
    batch = load_scenarios(path, indices)
    digests = scenario_digests(batch)
    examples = _examples_of_rows(df, batch, digests, indices, goal_predictor, choice=choice,
                                 where=(path, directory), progress=progress)
    info = {
        "prompt_style": "choice" if choice else "compact",
        "labels_dir": str(directory),
        "labels_sha256": labels_sha256(directory),
        "labels_manifest": {k: manifest.get(k) for k in ("dataset_digest", "n_scenarios", "n_propose", "n_refine",
                                                         "seed", "sf_params_sha256", "command")},
        "scenarios_path": str(path),
        "scenarios_digest": dataset_digest(digests),
        "n_label_rows": n_rows,
        "n_examples": len(examples),
        "n_scenarios": len(indices),
        "safe_only": safe_only,
    }
    return examples, info


def _examples_of_rows(
    df: pd.DataFrame,
    batch: ScenarioBatch,
    digests: np.ndarray,
    indices: np.ndarray,
    goal_predictor: GoalPredictor,
    *,
    choice: bool,
    where: tuple[Path, Path],
    progress: Callable[[int], None] | None,
) -> list[ChatExample]:
    """The chat examples of label rows ``df`` in (scenario index, kind) order; ``batch`` holds scenarios
    ``indices`` with their ``digests``; ``where`` (scenario file, labels directory) names a digest mismatch."""
    path, directory = where
    vehicles = vehicle_keys(batch)
    pos = {int(k): j for j, k in enumerate(indices)}
    goals = goal_predictor.predict_goals(batch).top
    descs: dict[int, Any] = {}
    examples: list[ChatExample] = []
    for _, row in df.sort_values(["scenario_index", "kind"], kind="stable").iterrows():
        j = pos[int(row["scenario_index"])]
        if digests[j] != row["scenario_digest"]:
            raise ValueError(f"{path}: row {int(row['scenario_index'])} has digest {digests[j]}, the labels in "
                             f"{directory} expect {row['scenario_digest']} (another scenario file?)")
        if j not in descs:
            descs[j] = describe_scenario(batch.take([j]), goals[j])
            if progress is not None:
                progress(1)
        if choice:  # weights by repetition: an example of weight w appears round(w) times (at least once)
            example = choice_example_of_row(row, descs[j], str(vehicles[j]))
            examples += [example] * max(1, round(float(row["weight"])))
        else:
            examples.append(example_of_row(row, descs[j], str(vehicles[j])))
    return examples


def build_examples_many(
    directories: Iterable[Path],
    goal_predictor: GoalPredictor,
    *,
    safe_only: bool = True,
    max_scenarios: int | None = None,
    progress: Callable[[int], None] | None = None,
) -> tuple[list[ChatExample], dict[str, Any]]:
    """``build_examples`` over several label directories, concatenated, with each one's provenance."""
    examples: list[ChatExample] = []
    infos: list[dict[str, Any]] = []
    for d in directories:
        ex, info = build_examples(Path(d), goal_predictor, safe_only=safe_only, max_scenarios=max_scenarios,
                                  progress=progress)
        examples += ex
        infos.append(info)
    styles = sorted({i["prompt_style"] for i in infos})
    if len(styles) > 1:
        raise ValueError(f"labels of different prompt styles ({', '.join(styles)}) cannot train one model: "
                         f"{', '.join(str(i['labels_dir']) for i in infos)}")
    info = {"prompt_style": styles[0] if styles else "compact", "sources": infos, "n_examples": len(examples),
            "labels_sha256": [i["labels_sha256"] for i in infos],
            "n_scenarios": int(sum(i["n_scenarios"] for i in infos))}
    return examples, info


def split_examples(examples: Sequence[ChatExample], val_fraction: float,
                   seed: int = 0) -> tuple[list[ChatExample], list[ChatExample]]:
    """(train, validation) by ego vehicle: ``val_fraction`` of the vehicles (seeded) are validation."""
    if val_fraction <= 0:
        return list(examples), []
    keys = np.array([e.vehicle_key or e.scenario_digest for e in examples], dtype=object)
    train_idx, val_idx = split_by_key(keys, 1.0 - val_fraction, seed)
    return [examples[i] for i in train_idx], [examples[i] for i in val_idx]
