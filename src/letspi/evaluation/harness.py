"""Run planners over scenarios, time them, compute metrics, and resume interrupted runs.

Layout of an evaluation directory::

    DIR/run.json                         scenarios file, its size and fingerprint (resume guard)
    DIR/per_scenario/<planner>/part-NNNNN.parquet   per-scenario metrics + plan info, in chunks
    DIR/metrics.json                     {"planners": {name: aggregated metrics}}
    DIR/metrics.md                       the paper-style table

Each chunk is written atomically after it is planned and scored, so a crash loses at most the
chunk in flight; rerunning skips scenarios whose ids are already in a part file.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from letspi.metrics.aggregate import AggValue, aggregate_metrics, render_markdown_table
from letspi.metrics.config import MetricsConfig
from letspi.metrics.evaluate import compute_metrics
from letspi.planners.base import Planner
from letspi.scenario.types import ScenarioBatch


class EvaluationDirError(ValueError):
    """The output directory belongs to a different evaluation (other scenarios)."""


def _fingerprint(batch: ScenarioBatch) -> str:
    h = hashlib.sha256()
    for sid in batch.scenario_id:
        h.update(str(sid).encode())
        h.update(b"\0")
    return h.hexdigest()[:16]


def _check_run_file(out_dir: Path, scenarios_file: str, batch: ScenarioBatch) -> None:
    run_file = out_dir / "run.json"
    record = {"scenarios_file": scenarios_file, "n_scenarios": len(batch), "fingerprint": _fingerprint(batch)}
    if run_file.exists():
        old = json.loads(run_file.read_text())
        if old.get("fingerprint") != record["fingerprint"]:
            raise EvaluationDirError(
                f"{out_dir} holds results for other scenarios ({old.get('scenarios_file')}, "
                f"{old.get('n_scenarios')} scenarios); use another --out or delete it"
            )
        return
    out_dir.mkdir(parents=True, exist_ok=True)
    run_file.write_text(json.dumps(record, indent=2))


def planner_dir_name(name: str) -> str:
    """A planner name as a directory name (model specs contain ':' and '/')."""
    return "".join(c if c.isalnum() or c in "-_.@+" else "_" for c in name)


def _done_ids(planner_dir: Path) -> set[str]:
    done: set[str] = set()
    for part in sorted(planner_dir.glob("part-*.parquet")):
        done.update(pd.read_parquet(part, columns=["scenario_id"])["scenario_id"].astype(str))
    return done


def _write_part(planner_dir: Path, frame: pd.DataFrame) -> Path:
    planner_dir.mkdir(parents=True, exist_ok=True)
    index = len(list(planner_dir.glob("part-*.parquet")))
    path = planner_dir / f"part-{index:05d}.parquet"
    tmp = path.with_name(path.name + ".tmp")
    frame.to_parquet(tmp, index=False)
    os.replace(tmp, path)
    return path


def _info_columns(info: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    cols: dict[str, np.ndarray] = {}
    for key, arr in info.items():
        a = np.asarray(arr)
        if a.ndim == 1:
            cols[f"info_{key}"] = a
        elif a.ndim == 2 and a.shape[1] <= 8:
            for k in range(a.shape[1]):
                cols[f"info_{key}_{k}"] = a[:, k]
    return cols


def planner_config_key(planner: Planner) -> str:
    """What identifies a planner's results beyond its name (LLM planners: model, prompt version,
    thresholds, memory; others: the name, which already carries non-default options)."""
    return str(getattr(planner, "config_key", planner.name))


def _check_planner_config(planner_dir: Path, planner: Planner) -> None:
    key = planner_config_key(planner)
    marker = planner_dir / "config.json"
    if marker.exists():
        old = json.loads(marker.read_text()).get("config_key")
        if old != key:
            raise EvaluationDirError(
                f"{planner_dir} holds results of {planner.name!r} with another configuration ({old}); "
                f"this run is {key}: use another --out or delete that directory"
            )
        return
    planner_dir.mkdir(parents=True, exist_ok=True)
    marker.write_text(json.dumps({"planner": planner.name, "config_key": key}, indent=2))


def run_planner(
    planner: Planner,
    batch: ScenarioBatch,
    out_dir: Path,
    config: MetricsConfig,
    progress: Callable[[int], None] | None = None,
) -> pd.DataFrame:
    """Plan and score every not-yet-done scenario with ``planner``; return all its per-scenario rows."""
    planner_dir = out_dir / "per_scenario" / planner_dir_name(planner.name)
    _check_planner_config(planner_dir, planner)
    done = _done_ids(planner_dir)
    todo = np.flatnonzero([str(s) not in done for s in batch.scenario_id])
    if progress is not None and len(batch) - len(todo):
        progress(len(batch) - len(todo))
    step = max(1, int(planner.batch_size))
    for start in range(0, len(todo), step):
        idx = todo[start : start + step]
        sub = batch.take(idx)
        t0 = time.perf_counter()
        plan = planner.plan(sub)
        elapsed_s = time.perf_counter() - t0
        metrics = compute_metrics(sub, plan.xy_m, plan.vxy_mps, plan.goals_xy_m, config)
        frame = metrics.to_frame()
        frame.insert(0, "scenario_id", [str(s) for s in sub.scenario_id])
        frame["inference_s"] = elapsed_s / len(idx)
        for name, col in _info_columns(plan.info).items():
            frame[name] = col
        _write_part(planner_dir, frame)
        if progress is not None:
            progress(len(idx))
    return load_planner_results(out_dir, planner.name)


def load_planner_results(out_dir: Path, planner_name: str) -> pd.DataFrame:
    parts = sorted((out_dir / "per_scenario" / planner_dir_name(planner_name)).glob("part-*.parquet"))
    if not parts:
        return pd.DataFrame()
    frame = pd.concat([pd.read_parquet(p) for p in parts], ignore_index=True)
    return frame.drop_duplicates("scenario_id", keep="first")


def evaluate(
    planners: Sequence[Planner],
    batch: ScenarioBatch,
    out_dir: Path,
    *,
    scenarios_file: str = "",
    config: MetricsConfig | None = None,
    progress_factory: Callable[[str, int], Callable[[int], None]] | None = None,
) -> dict[str, dict[str, AggValue]]:
    """Evaluate ``planners`` on ``batch``; write per-scenario parts, metrics.json and metrics.md.

    Returns ``{planner_name: aggregated metrics}`` (keys documented in ``letspi.metrics.aggregate``).
    """
    config = config or MetricsConfig()
    out_dir = Path(out_dir)
    _check_run_file(out_dir, scenarios_file, batch)
    results: dict[str, dict[str, AggValue]] = {}
    for planner in planners:
        progress = progress_factory(planner.name, len(batch)) if progress_factory else None
        frame = run_planner(planner, batch, out_dir, config, progress)
        results[planner.name] = aggregate_metrics(frame)
    # merge with planners evaluated earlier in the same directory, so the table is complete
    metrics_file = out_dir / "metrics.json"
    merged: dict[str, dict[str, AggValue]] = {}
    if metrics_file.exists():
        merged = json.loads(metrics_file.read_text()).get("planners", {})
    merged.update(results)
    metrics_file.write_text(json.dumps({"planners": merged}, indent=2, allow_nan=False, default=float))
    (out_dir / "metrics.md").write_text(render_markdown_table(merged) + "\n")
    return merged
