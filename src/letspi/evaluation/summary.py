"""metrics.json and metrics.md from stored rows: timing, planner outputs' aggregates, intervals, paired comparisons.

Inference time averages only rows whose model calls really ran (``llm_cached`` False; cached rows counted apart,
loading is ``model_load_s``). Declared planner outputs add their keys; their rates carry intervals and paired tests.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from letspi.assembly.planner_table import BUILT_IN
from letspi.evaluation.results import load_planner_results
from letspi.fsutil import atomic_write_text
from letspi.metrics.aggregate import AggValue, apply_agg, render_markdown_table
from letspi.metrics.config import MetricsConfig
from letspi.metrics.registry import HOW_DOC, Metric
from letspi.metrics.uncertainty import (
    GROUP_COLUMN,
    Statistic,
    align,
    design_effects,
    intervals_of,
    metric_statistics,
    n_groups,
    paired,
    paired_of,
    rate_statistic,
    statistics_record,
)
from letspi.planners.decision import DECISION
from letspi.planners.llm import LLM_CACHED
from letspi.planners.outputs import by_column, column
from letspi.simulation.config import EvaluationMode
from letspi.simulation.store import CLOSED_LOOP_OUTPUTS


def known_outputs(extra: Sequence[Metric] = ()) -> dict[str, Metric]:
    """Results column -> declared output: every built-in planner kind's, the closed loop's, then ``extra``."""
    return by_column((*BUILT_IN.outputs(), *CLOSED_LOOP_OUTPUTS, *extra))


def cached(frame: pd.DataFrame) -> np.ndarray:
    """(n,) True for rows whose model calls were all served by the response cache."""
    col = column(LLM_CACHED)
    return np.asarray(frame[col], dtype=bool) if col in frame else np.zeros(len(frame), dtype=bool)


def live_inference_s(frame: pd.DataFrame) -> np.ndarray:
    """Per-scenario planning times [s] of the rows whose model calls really ran (all rows without a model)."""
    t = np.asarray(frame["inference_s"], dtype=np.float64) if len(frame) else np.zeros(0)
    return t[~cached(frame)]


def timing_summary(frame: pd.DataFrame, load_s: float, outputs: Mapping[str, Metric] | None = None,
                   config: MetricsConfig | None = None) -> dict[str, AggValue]:
    """Inference time of one planner's rows (cached rows apart, loading apart) and the aggregates of every
    declared output present (``outputs``: column -> output; later columns win a shared key)."""
    is_cached = cached(frame)
    live = live_inference_s(frame)
    out: dict[str, AggValue] = {
        "inference_s": float(live.mean()) if len(live) else None,
        "inference_n": len(live),
        "inference_cached_n": int(is_cached.sum()),
        "inference_p50_s": float(np.percentile(live, 50)) if len(live) else None,
        "inference_p95_s": float(np.percentile(live, 95)) if len(live) else None,
        "model_load_s": round(float(load_s), 3),
    }
    config = config or MetricsConfig()
    for col, metric in (known_outputs() if outputs is None else outputs).items():
        if col in frame and len(frame):
            values = frame[col].to_numpy()
            out.update({agg.key: apply_agg(agg, values, config) for agg in metric.aggregates})
    return out


def decision_shares(frames: Mapping[str, pd.DataFrame]) -> dict[str, dict[str, float]]:
    """Per deciding planner (its ``decision`` output), the share [%] of each decision."""
    out: dict[str, dict[str, float]] = {}
    col = column(DECISION)
    for name, frame in frames.items():
        if col in frame and len(frame):
            counts = frame[col].astype(str).value_counts()
            out[name] = {str(k): float(100.0 * v / len(frame)) for k, v in sorted(counts.items())}
    return out


def output_rates(outputs: Mapping[str, Metric]) -> list[tuple[str, str]]:
    """(key, results column) of every declared output's rate: the keys that carry an interval."""
    return [(agg.key, col) for col, metric in outputs.items() for agg in metric.aggregates if agg.how == "pct"]


def planner_statistics(frame: pd.DataFrame, config: MetricsConfig | None = None,
                       outputs: Mapping[str, Metric] | None = None) -> dict[str, Statistic]:
    """The per-scenario values behind one planner's rates and means (for intervals and paired tests): metric keys
    and output rates. ``inference_s``: live rows only, and only when most rows were timed one by one (a batch
    planner's rows share one mean time, whose spread says nothing)."""
    if "inference_s" in frame:
        timed = np.where(cached(frame), np.nan, np.asarray(frame["inference_s"], dtype=np.float64))
        live = timed[np.isfinite(timed)]
        frame = frame.assign(inference_s=timed) if 2 * len(np.unique(live)) > len(live) else frame.drop(
            columns="inference_s")
    out = metric_statistics(frame, config)
    for key, col in output_rates(known_outputs() if outputs is None else outputs):
        if col in frame and len(frame):
            try:
                out[key] = rate_statistic(key, frame[col])
            except ValueError:  # not a 0/1 flag per scenario: no interval
                pass
    return out


def _paired_subject(frame: pd.DataFrame, reference: pd.DataFrame, config: MetricsConfig | None,
                    outputs: Mapping[str, Metric] | None = None
                    ) -> tuple[dict[str, Statistic], dict[str, Statistic], np.ndarray]:
    mine, theirs = align(frame, reference)
    return (planner_statistics(mine, config, outputs), planner_statistics(theirs, config, outputs),
            mine[GROUP_COLUMN].to_numpy())


def paired_record(frame: pd.DataFrame, reference: pd.DataFrame, config: MetricsConfig | None = None
                  ) -> dict[str, dict[str, Any]]:
    """Key -> the paired comparison of a planner's rows with a reference's (``letspi.metrics.uncertainty``),
    over the scenario digests both have; both frames need ``GROUP_COLUMN``."""
    return paired(*_paired_subject(frame, reference, config))


def choose_reference(names: Sequence[str], requested: str | None, first: str | None = None) -> str | None:
    """The planner every other is compared with: ``requested``, else ``sf`` when present, else ``first``
    (the first planner of this run), else the first name; None with fewer than two planners."""
    if requested is not None:
        if requested not in names:
            raise ValueError(f"--reference {requested!r} is not among the planners ({', '.join(names) or 'none'})")
        return requested if len(names) > 1 else None
    if len(names) < 2:
        return None
    if "sf" in names:
        return "sf"
    return first if first in names else names[0]


def uncertainty_summary(frames: dict[str, pd.DataFrame], config: MetricsConfig | None,
                        reference: str | None, outputs: Mapping[str, Metric] | None = None) -> dict[str, Any]:
    """metrics.json's "intervals", "paired" (when there is a reference) and "statistics" of the planners'
    stored rows (``frames``, each with ``GROUP_COLUMN``)."""
    stats = {name: planner_statistics(f, config, outputs) for name, f in frames.items()}
    out: dict[str, Any] = {
        "intervals": intervals_of({name: (stats[name], f[GROUP_COLUMN].to_numpy()) for name, f in frames.items()})}
    if reference is not None and reference in frames:
        out["paired"] = {"reference": reference, "planners": paired_of(
            {name: _paired_subject(f, frames[reference], config, outputs) for name, f in frames.items()
             if name != reference})}
    keys: dict[str, Statistic] = {}
    for s in stats.values():
        keys.update({k: v for k, v in s.items() if k not in keys})
    out["statistics"] = {**statistics_record(keys=keys),
                         "n_vehicles": {name: n_groups(f[GROUP_COLUMN].to_numpy()) for name, f in frames.items()},
                         "design_effects": {name: design_effects(stats[name], f[GROUP_COLUMN].to_numpy())
                                            for name, f in frames.items()}}
    return out


def summary_markdown(summary: dict[str, Any], names: Sequence[str] | None = None) -> str:
    """The tables of a metrics.json (``read_summary``) with intervals and the paired comparison, for
    ``names`` (default: every planner; the reference's comparisons are kept for the others)."""
    planners: dict[str, dict[str, AggValue]] = summary.get("planners", {})
    chosen = list(planners) if names is None else [n for n in names if n in planners]
    pairs = summary.get("paired")
    if isinstance(pairs, dict):
        pairs = {**pairs, "planners": {n: v for n, v in pairs.get("planners", {}).items() if n in chosen}}
    mode = summary.get("run", {}).get("mode", EvaluationMode.OPEN_LOOP.value)
    mode_line = (f"Mode: {mode} (per planner replanning period: per_scenario/*/config.json)\n\n"
                 if mode != EvaluationMode.OPEN_LOOP else "")
    return mode_line + render_markdown_table({n: planners[n] for n in chosen}, intervals=summary.get("intervals"),
                                             paired=pairs)


def write_summary(out_dir: Path, record: dict[str, Any], results: dict[str, dict[str, AggValue]],
                  write_run_file: Callable[[], None], vehicles: np.ndarray, config: MetricsConfig,
                  reference: str | None = None, first: str | None = None,
                  outputs: Mapping[str, Metric] | None = None) -> dict[str, dict[str, AggValue]]:
    """Merge ``results`` into metrics.json / metrics.md (planners of earlier runs kept), with the
    intervals and paired comparisons of every stored planner (``vehicles``: (B,) vehicle of each
    dataset row; ``outputs``: column -> declared output, default ``known_outputs()``); returns all aggregates."""
    write_run_file()
    metrics_file = out_dir / "metrics.json"
    merged: dict[str, dict[str, AggValue]] = {}
    if metrics_file.exists():
        merged = json.loads(metrics_file.read_text()).get("planners", {})
    merged.update(results)
    frames = {}
    for name in merged:
        frame = load_planner_results(out_dir, name)
        if len(frame):  # the dataset's vehicles, also for rows stored before parts had the column
            frames[name] = frame.assign(**{GROUP_COLUMN: vehicles[frame["row"].to_numpy(dtype=np.int64)]})
    summary = uncertainty_summary(frames, config, choose_reference(list(frames), reference, first), outputs)
    payload = {"run": {"key": record["key"], **record["identity"], "dataset": record["dataset"]}, "planners": merged,
               **summary}
    decisions = decision_shares(frames)
    if decisions:
        payload["decisions"] = decisions
    atomic_write_text(metrics_file, json.dumps(payload, indent=2, allow_nan=False, default=float) + "\n")
    atomic_write_text(out_dir / "metrics.md", summary_markdown(payload) + "\n")
    return merged


def outputs_reference_markdown() -> str:
    """Markdown reference of the planners' declared outputs (built-in kinds) and the closed loop's columns."""
    kinds_of: dict[str, list[str]] = {}
    for kind in BUILT_IN.kinds:
        for o in kind.outputs or ():
            kinds_of.setdefault(o.name, []).append(kind.name)
    lines = ["Planner outputs (``PlannerKind.outputs``, ``letspi.planners.outputs``): what each planner reports per "
             "scenario beside its plan, stored as `info_<name>` (a (B, K) output as `info_<name>_0` ...), with the "
             "`metrics.json` keys it adds:", "",
             "| column | unit | dtype | meaning | keys | planners |", "|---|---|---|---|---|---|"]

    def row(o: Metric, who: str) -> str:
        keys = ", ".join(f"`{a.key}` ({HOW_DOC[a.how].format(t=a.threshold)})" for a in o.aggregates)
        return f"| `{column(o)}` | {o.unit} | {o.dtype} | {o.doc} | {keys} | {who} |"

    lines += [row(o, ", ".join(kinds_of[o.name])) for o in BUILT_IN.outputs()]
    lines += ["", "Closed-loop columns (``letspi.simulation.store.CLOSED_LOOP_OUTPUTS``); every output `x` of the "
              "planner is also stored as its mean over the window's replans, `info_x_mean_over_replans`:", "",
              "| column | unit | dtype | meaning | keys | planners |", "|---|---|---|---|---|---|"]
    lines += [row(o, "every planner in closed loop") for o in CLOSED_LOOP_OUTPUTS]
    return "\n".join(lines) + "\n"
