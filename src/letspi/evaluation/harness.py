"""Run planners over scenarios, time them, score them, store their plans, and resume interrupted runs.

Layout of an evaluation directory::

    DIR/run.json                        what the results are keyed by: dataset digest, metrics
                                        configuration, evaluation mode, letspi version
    DIR/per_scenario/<name>/config.json the planner's full configuration and its content key
    DIR/per_scenario/<name>/part-*.parquet  per-scenario metrics, timing, plan info and the plan
                                        itself (ego xy / velocity, float32), one file per chunk
    DIR/metrics.json                    {"planners": {name: aggregated metrics}, "run": ...}
    DIR/metrics.md                      the paper-style table

Keys: a directory holds one dataset (the digest of its scenarios' contents, ``letspi.scenario.identity``)
under one metrics configuration and mode; another is refused, naming what differs. Each planner name
holds one planner configuration (``letspi.planners.config``); another configuration under the same
name is refused with the differing fields (label variants ``LABEL=KIND``). Rows are keyed by
scenario digest, so a resumed run skips exactly the scenarios already scored.

Crash safety: every file is written to a temporary, fsynced and renamed (``letspi.fsutil``); part
files have unique names. A killed run loses at most the chunk in flight; rerunning completes it and
gives the same results as an uninterrupted run. No partial output: ``run.json`` and a planner's
directory and ``config.json`` are written with the first stored part (the keys are checked before
planning), so a planner that fails before storing a scenario (server down, disk full, Ctrl-C) leaves
nothing; the planners finished before a failure are still merged into metrics.json / metrics.md.

Concurrency: planners that call a model per scenario and are thread-safe (the LLM planners) keep
``concurrency`` scenarios' proposals in flight (``letspi.evaluation.concurrent``; default per LLM
backend); one thread simulates, scores and writes their rows per part in scenario order, so the
concurrency never changes stored results and is not part of any key. A scenario whose LLM requests
failed in transport is not stored: that planner's metrics are not aggregated and ``evaluate`` ends
with ``ScenariosFailedError`` (rerun to complete).

Modes: ``open-loop`` (the paper's protocol) is run here; ``closed-loop-log``, ``closed-loop-reactive``
and ``closed-loop-hybrid`` run through ``letspi.evaluation.closed_loop`` (a ``PlannerRunner`` passed to
``evaluate``) into the same layout: the mode and its settings join ``run.json``'s identity and each
planner's key gets ``evaluation = {mode, replan_s}``, so one directory never mixes modes or periods.

Planner contract: planners that do not read the future (``BuiltPlanner.reads_future`` False, from
the planner table) get the history-only view of each batch (``ScenarioBatch.history()``); metrics use the full batch.

Timing: ``inference_s`` is the wall time of ``plan`` per scenario. For LLM planners the table's
inference time averages only rows whose model calls really ran (``info_llm_cached`` False); cached
rows are counted apart (``inference_cached_n``) with the latency recorded when their replies were
made (``llm_original_latency_s``); model loading is ``model_load_s``, outside every row.
"""

from __future__ import annotations

import functools
import json
import time
import uuid
from collections.abc import Callable, Mapping, Sequence
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any, Final

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from letspi.assembly.planners import BuiltPlanner
from letspi.assembly.planners import build_planner as assemble_planner
from letspi.constants import N_FUTURE
from letspi.evaluation.concurrent import plan_concurrently, planner_concurrency, runs_per_scenario
from letspi.execution.interrupt import WorkerPool
from letspi.execution.ordered import RunnerConfig, RunStats, RunStatus, ScenariosFailedError
from letspi.fsutil import atomic_write, atomic_write_text, remove_stale_temporaries
from letspi.metrics.aggregate import AggValue, aggregate_metrics, render_markdown_table
from letspi.metrics.compute import ScenarioMetrics, compute_metrics
from letspi.metrics.config import MetricsConfig
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
from letspi.planners.config import diff, key_of
from letspi.scenario.identity import dataset_digest, scenario_digests
from letspi.scenario.split import vehicle_keys
from letspi.scenario.store import load_scenarios
from letspi.scenario.types import ScenarioBatch
from letspi.simulation.config import EvaluationMode
from letspi.simulation.spec import PlannerSpec

RUN_FORMAT: Final = 2
PLAN_COLUMNS: Final = ("plan_xy_m", "plan_vxy_mps", "plan_goal_xy_m")
#: prefix of the large per-scenario array columns of closed-loop parts (replan plans, simulated
#: neighbours); read only with ``with_plans``
TRAJECTORY_PREFIX: Final = "cl_"
#: (advance by k scenarios, the concurrent runner's status or None)
ProgressCallback = Callable[[int, RunStatus | None], None]
ProgressFactory = Callable[[str, int], ProgressCallback]
#: runs one planner on the scenarios not yet stored and returns all its rows (``run_planner``'s
#: signature; closed loop: ``letspi.evaluation.closed_loop.ClosedLoopRunner``)
#: A way to run one planner (open loop: ``run_planner``; closed loop: ``closed_loop.ClosedLoopRunner``):
#: (planner, batch, digests, out_dir, metrics config, progress, before_write) -> (its rows, run stats).
#: ``before_write()`` must run before each part is written (``PartWriter`` does).
PlannerRunner = Callable[[BuiltPlanner, ScenarioBatch, np.ndarray, Path, MetricsConfig, ProgressCallback | None,
                          Callable[[], None] | None], tuple[pd.DataFrame, RunStats | None]]


class EvaluationDirError(ValueError):
    """The output directory holds results of another dataset, metrics configuration, mode or planner
    configuration (the message names what differs)."""


def letspi_version() -> str:
    try:
        return version("letspi")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "unknown"


def planner_dir_name(name: str) -> str:
    """A planner label as a directory name (labels may contain ':' and '/')."""
    return "".join(c if c.isalnum() or c in "-_.@+" else "_" for c in name)


# ------------------------------------------------------------------------------------------------
# Keys
# ------------------------------------------------------------------------------------------------


def run_record(batch: ScenarioBatch, digests: np.ndarray, scenarios_file: str, config: MetricsConfig,
               mode: EvaluationMode, mode_settings: dict[str, Any] | None = None) -> dict[str, Any]:
    """What ``run.json`` holds: the identity of the results (``identity``) and descriptive fields.

    ``mode_settings``: what else of the mode changes answers (closed loop: the simulation; with SUMO-driven
    neighbours the driver model; in ``closed-loop-hybrid`` the hand-over rule and scripted neighbours);
    absent in open loop, so open-loop keys are unchanged.
    """
    identity: dict[str, Any] = {
        "format": RUN_FORMAT,
        "mode": EvaluationMode(mode).value,
        "dataset_digest": dataset_digest(digests),
        "metrics_config": config.recorded(),
    }
    if mode_settings:
        identity["mode_settings"] = mode_settings
    return {
        "identity": identity,
        "key": key_of(identity),
        "dataset": {"file": scenarios_file, "n_scenarios": len(batch)},
        "letspi_version": letspi_version(),
    }


def _check_run_file(out_dir: Path, record: dict[str, Any]) -> bool:
    """Refuse a directory keyed differently; True if ``run.json`` is still to be written (it is written
    with the first stored results, so a run that stored nothing leaves no ``run.json``)."""
    run_file = out_dir / "run.json"
    if run_file.exists():
        old = json.loads(run_file.read_text())
        old_identity: dict[str, Any] = old.get("identity") or {"format": old.get("format", 1)}
        if old_identity != record["identity"]:
            changes = diff(old_identity, record["identity"])
            what = "; ".join(changes)
            new_digest = record["identity"]["dataset_digest"]
            if "dataset_digest" in old_identity and old_identity["dataset_digest"] != new_digest:
                was, now = old.get("dataset", {}), record["dataset"]
                what = (f"other scenarios: the directory holds {was.get('n_scenarios')} scenarios from "
                        f"{was.get('file') or '?'}, this run {now['n_scenarios']} from {now['file'] or '?'} "
                        f"(dataset digest {old_identity.get('dataset_digest')} vs "
                        f"{record['identity']['dataset_digest']}); " + what)
            raise EvaluationDirError(f"{out_dir} holds results keyed differently ({what}); "
                                     "use another --out or delete it")
        return False
    return True


def planner_record(built: BuiltPlanner, evaluation: dict[str, Any] | None = None) -> dict[str, Any]:
    """What ``per_scenario/<label>/config.json`` holds. ``evaluation``: how the planner was run when
    that changes its answers (closed loop: mode and replanning period); it joins the identity and
    the key, so an open-loop key stays the planner configuration's own."""
    identity = built.config.identity()
    key = built.key
    if evaluation:
        identity = {**identity, "evaluation": evaluation}
        key = key_of(identity)
    record: dict[str, Any] = {"name": built.name, "kind": built.config.kind, "key": key, "identity": identity,
                              "config": built.config.record()}
    if evaluation:
        record["evaluation"] = evaluation
    return record


def check_planner_config(planner_dir: Path, built: BuiltPlanner, evaluation: dict[str, Any] | None = None) -> bool:
    """Refuse another configuration under this planner's name; True if ``config.json`` is still to be
    written (with the planner's first part: a planner that stored nothing leaves no directory)."""
    marker = planner_dir / "config.json"
    record = planner_record(built, evaluation)
    if marker.exists():
        old = json.loads(marker.read_text())
        if old.get("key") != record["key"]:
            changes = diff(old.get("identity") or {}, record["identity"])
            version = record["identity"].get("version")  # a label for the new one: by its version, else its key
            bumped = version is not None and (old.get("identity") or {}).get("version") != version
            label = f"{built.name}-" + (f"v{version}" if bumped else str(record["key"])[:6])
            raise EvaluationDirError(
                f"{planner_dir} holds results of {built.name!r} with another configuration "
                f"(key {old.get('key')} vs {record['key']}: {'; '.join(changes) or 'older letspi format'}); "
                f"use another --out, or give this configuration its own label ({built.relabel(label)})")
        return False
    return True


def _remove_empty_dirs(*directories: Path) -> None:
    """Remove ``directories`` (innermost first) that are empty: a failed run leaves no empty shells."""
    for d in directories:
        try:
            d.rmdir()
        except OSError:  # not empty, or already gone
            pass


# ------------------------------------------------------------------------------------------------
# Parts
# ------------------------------------------------------------------------------------------------


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


def _fixed_list(arr: np.ndarray) -> pa.FixedSizeListArray:
    flat = np.ascontiguousarray(arr, dtype=np.float32).reshape(len(arr), -1)
    return pa.FixedSizeListArray.from_arrays(pa.array(flat.reshape(-1)), flat.shape[1])


def write_part(planner_dir: Path, frame: pd.DataFrame, plan_xy: np.ndarray, plan_vxy: np.ndarray,
               goals: np.ndarray, arrays: dict[str, np.ndarray] | None = None) -> Path:
    """One part file: ``frame``'s rows plus the plan columns and, optionally, more per-row arrays
    (``arrays``: name -> (K, ...), stored flat as float32; names start with ``TRAJECTORY_PREFIX``)."""
    table = pa.Table.from_pandas(frame, preserve_index=False)
    for name, arr in zip(PLAN_COLUMNS, (plan_xy, plan_vxy, goals), strict=True):
        table = table.append_column(name, _fixed_list(arr))
    for name, arr in (arrays or {}).items():
        if not name.startswith(TRAJECTORY_PREFIX):
            raise ValueError(f"extra part column {name!r} must start with {TRAJECTORY_PREFIX!r}")
        table = table.append_column(name, _fixed_list(arr))
    path = planner_dir / f"part-{uuid.uuid4().hex[:16]}.parquet"
    return atomic_write(path, lambda tmp: pq.write_table(table, tmp, compression="zstd"))


def _parts(planner_dir: Path) -> list[Path]:
    return sorted(planner_dir.glob("part-*.parquet"))


class PartWriter:
    """Writes one planner's part files. Its directory and ``config.json`` appear with the first part
    (``before_write()`` runs before each part, e.g. to write ``run.json``); ``abandon()`` after a
    failure removes a ``config.json`` no part followed and empty directories, so a planner that
    stored nothing leaves nothing. One writer thread per planner: no locking."""

    def __init__(self, out_dir: Path, built: BuiltPlanner, evaluation: dict[str, Any] | None = None,
                 before_write: Callable[[], None] | None = None) -> None:
        self.planner_dir = out_dir / "per_scenario" / planner_dir_name(built.name)
        if self.planner_dir.is_dir():
            remove_stale_temporaries(self.planner_dir)
        self._record = planner_record(built, evaluation)
        self._config_pending = check_planner_config(self.planner_dir, built, evaluation)
        self._wrote_config = False
        self._before_write = before_write

    def done(self) -> set[str]:
        """Digests of the scenarios already stored."""
        return done_digests(self.planner_dir)

    def todo(self, digests: np.ndarray, progress: ProgressCallback | None = None) -> np.ndarray:
        """Indices of the scenarios ``digests`` (B,) not stored yet; the stored ones are reported to
        ``progress`` as done (a rerun resumes)."""
        done = self.done()
        todo = np.flatnonzero([d not in done for d in digests])
        if progress is not None and len(digests) - len(todo):
            progress(len(digests) - len(todo), None)
        return todo

    def write(self, frame: pd.DataFrame, plan_xy: np.ndarray, plan_vxy: np.ndarray, goals: np.ndarray,
              arrays: dict[str, np.ndarray] | None = None) -> Path:
        if self._before_write is not None:
            self._before_write()
        if self._config_pending:
            atomic_write_text(self.planner_dir / "config.json", json.dumps(self._record, indent=2) + "\n")
            self._config_pending = False
            self._wrote_config = True
        return write_part(self.planner_dir, frame, plan_xy, plan_vxy, goals, arrays)

    def abandon(self) -> None:
        if self._wrote_config and not _parts(self.planner_dir):  # e.g. the first part hit a full disk
            (self.planner_dir / "config.json").unlink(missing_ok=True)
        _remove_empty_dirs(self.planner_dir)


def done_digests(planner_dir: Path) -> set[str]:
    done: set[str] = set()
    for part in _parts(planner_dir):
        done.update(pq.read_table(part, columns=["scenario_digest"]).column(0).to_pylist())
    return done


def stored_rows(out_dir: Path, planner_names: Sequence[str]) -> int:
    """Scenario rows stored in ``out_dir`` for ``planner_names`` (what an interrupted run keeps; a
    directory holds one dataset, so no digest needs computing)."""
    return sum(len(done_digests(Path(out_dir) / "per_scenario" / planner_dir_name(n))) for n in planner_names)


def load_planner_results(out_dir: Path, planner_name: str, *, with_plans: bool = False,
                         digests: np.ndarray | None = None) -> pd.DataFrame:
    """All stored rows of one planner, in dataset order (``row``), one per scenario digest; with
    ``digests``, only the rows of those scenarios.

    ``with_plans`` keeps the plan columns (``plan_xy_m`` etc. as flat float32 arrays per row).
    """
    parts = _parts(Path(out_dir) / "per_scenario" / planner_dir_name(planner_name))
    if not parts:
        return pd.DataFrame()
    frames = []
    for p in parts:
        names = pq.read_schema(p).names
        cols = names if with_plans else [c for c in names
                                         if c not in PLAN_COLUMNS and not c.startswith(TRAJECTORY_PREFIX)]
        frames.append(pq.read_table(p, columns=cols).to_pandas())
    frame = pd.concat(frames, ignore_index=True).drop_duplicates("scenario_digest", keep="first")
    if digests is not None:
        frame = frame[frame["scenario_digest"].isin(set(digests))]
    return frame.sort_values("row", kind="stable").reset_index(drop=True)


def load_plans(out_dir: Path, planner_name: str) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Stored plans of one planner: scenario id -> (xy (F, 2), vxy (F, 2), goal (2,)) float64."""
    frame = load_planner_results(out_dir, planner_name, with_plans=True)
    out = {}
    for row in frame.itertuples(index=False):
        xy = np.asarray(row.plan_xy_m, dtype=np.float64).reshape(N_FUTURE, 2)
        vxy = np.asarray(row.plan_vxy_mps, dtype=np.float64).reshape(N_FUTURE, 2)
        out[str(row.scenario_id)] = (xy, vxy, np.asarray(row.plan_goal_xy_m, dtype=np.float64))
    return out


# ------------------------------------------------------------------------------------------------
# Running
# ------------------------------------------------------------------------------------------------


def _scored_frame(metrics: ScenarioMetrics, scenario_ids: np.ndarray, idx: np.ndarray, digests: np.ndarray,
                  vehicles: np.ndarray, info: dict[str, np.ndarray], inference_s: float | np.ndarray) -> pd.DataFrame:
    """The stored rows of scenarios ``idx``: ids, ego vehicle, metrics, planning time per scenario, plan info."""
    frame = metrics.to_frame()
    columns: dict[str, Any] = {"scenario_id": [str(s) for s in scenario_ids],
                               "scenario_digest": [str(d) for d in digests[idx]], "row": idx.astype(np.int64),
                               GROUP_COLUMN: [str(v) for v in vehicles[idx]]}
    tail: dict[str, Any] = {"inference_s": np.broadcast_to(np.asarray(inference_s, dtype=np.float64), (len(idx),)),
                            **_info_columns(info)}
    return pd.concat([pd.DataFrame(columns), frame, pd.DataFrame(tail)], axis=1)


def run_planner(
    built: BuiltPlanner,
    batch: ScenarioBatch,
    digests: np.ndarray,
    out_dir: Path,
    config: MetricsConfig,
    progress: ProgressCallback | None = None,
    *,
    concurrency: int | None = None,
    before_write: Callable[[], None] | None = None,
) -> tuple[pd.DataFrame, RunStats | None]:
    """Plan and score every scenario of ``batch`` not yet stored for ``built``; return all its rows and,
    for per-scenario planners, the run's ``RunStats`` (``concurrency``: None = the backend's default).

    The planner's directory and ``config.json`` appear with its first part (``before_write()`` runs
    before each part is written): a planner that fails before storing anything leaves nothing."""
    writer = PartWriter(out_dir, built, before_write=before_write)
    todo = writer.todo(digests, progress)
    try:
        run = _plan_and_store(built, batch, digests, todo, config, progress, concurrency, writer.write)
    except BaseException:
        writer.abandon()
        raise
    return load_planner_results(out_dir, built.name, digests=digests), run


def _plan_and_store(built: BuiltPlanner, batch: ScenarioBatch, digests: np.ndarray, todo: np.ndarray,
                    config: MetricsConfig, progress: ProgressCallback | None, concurrency: int | None,
                    store_part: Callable[[pd.DataFrame, np.ndarray, np.ndarray, np.ndarray], Path]) -> RunStats | None:
    planner = built.planner
    vehicles = vehicle_keys(batch)
    run: RunStats | None = None
    if runs_per_scenario(planner):
        run = plan_concurrently(
            planner, batch, [int(i) for i in todo], reads_future=built.reads_future,
            measure=lambda sub, plan: compute_metrics(sub, plan.xy_m, plan.vxy_mps, plan.goals_xy_m, config),
            write_part=lambda metrics, idx, plan, seconds: store_part(
                _scored_frame(metrics, batch.scenario_id[idx], idx, digests, vehicles, plan.info, seconds),
                plan.xy_m, plan.vxy_mps, plan.goals_xy_m),
            runner=RunnerConfig(concurrency=planner_concurrency(planner, concurrency)), progress=progress)
    else:
        step = max(1, int(planner.batch_size))
        for start in range(0, len(todo), step):
            idx = todo[start : start + step]
            sub = batch.take(idx)
            seen = sub if built.reads_future else sub.history()
            t0 = time.perf_counter()
            plan = planner.plan(seen)
            elapsed_s = time.perf_counter() - t0
            metrics = compute_metrics(sub, plan.xy_m, plan.vxy_mps, plan.goals_xy_m, config)
            frame = _scored_frame(metrics, sub.scenario_id, idx, digests, vehicles, plan.info, elapsed_s / len(idx))
            store_part(frame, plan.xy_m, plan.vxy_mps, plan.goals_xy_m)
            if progress is not None:
                progress(len(idx), None)
    return run


@functools.lru_cache(maxsize=1)
def _scenarios_by_digest(scenarios_file: str) -> tuple[ScenarioBatch, dict[str, int]]:
    """A scenario file and the row of each scenario digest, read once per worker process."""
    full = load_scenarios(Path(scenarios_file))
    return full, {str(d): i for i, d in enumerate(scenario_digests(full))}


def _planner_parts(spec: PlannerSpec, scenarios_file: str, digests: list[str], out_dir: str,
                   config: MetricsConfig) -> None:
    """A worker process's share of ``evaluate(..., workers=N)``: one planner's parts for the scenarios
    ``digests`` (read from ``scenarios_file``, in that order: the rows of this process's batch)."""
    built = assemble_planner(spec.config, spec.name, table=spec.table())
    full, row_of = _scenarios_by_digest(scenarios_file)
    missing = [d for d in digests if d not in row_of]
    if missing:
        raise ValueError(f"{scenarios_file} does not hold {len(missing)} of the evaluated scenarios: evaluate "
                         "them in one process (workers=0)")
    batch = full.take(np.array([row_of[d] for d in digests], dtype=np.int64))
    run_planner(built, batch, np.asarray(digests, dtype=object), Path(out_dir), config)


def store_in_workers(planners: Sequence[BuiltPlanner], scenarios_file: str, digests: np.ndarray, out_dir: Path,
                     config: MetricsConfig, workers: int) -> None:
    """Store the parts of batch ``planners`` in ``workers`` spawned processes, one planner per task: each
    plans the batches it would plan in this process (identical rows) and the planners share the cores."""
    specs = [PlannerSpec.of_built(b) for b in planners]
    with WorkerPool(min(workers, len(specs))) as pool:
        futures = [pool.submit(_planner_parts, s, scenarios_file, [str(d) for d in digests], str(out_dir), config)
                   for s in specs]
        for future in futures:
            future.result()


def _cached(frame: pd.DataFrame) -> np.ndarray:
    return (np.asarray(frame["info_llm_cached"], dtype=bool) if "info_llm_cached" in frame
            else np.zeros(len(frame), dtype=bool))


def live_inference_s(frame: pd.DataFrame) -> np.ndarray:
    """Per-scenario planning times [s] of the rows whose model calls really ran (all rows of planners
    without a model)."""
    t = np.asarray(frame["inference_s"], dtype=np.float64) if len(frame) else np.zeros(0)
    return t[~_cached(frame)]


def timing_summary(frame: pd.DataFrame, load_s: float) -> dict[str, AggValue]:
    """Honest inference time of one planner's rows (rules in the module docstring)."""
    cached = _cached(frame)
    live = live_inference_s(frame)
    out: dict[str, AggValue] = {
        "inference_s": float(live.mean()) if len(live) else None,
        "inference_n": len(live),
        "inference_cached_n": int(cached.sum()),
        "inference_p50_s": float(np.percentile(live, 50)) if len(live) else None,
        "inference_p95_s": float(np.percentile(live, 95)) if len(live) else None,
        "model_load_s": round(float(load_s), 3),
    }
    if "info_llm_original_latency_s" in frame:
        orig = np.asarray(frame["info_llm_original_latency_s"], dtype=np.float64)
        out["llm_original_latency_s"] = float(orig.mean()) if len(orig) else None
        # closed loop: the calls of all replans
        calls = "info_llm_calls_total" if "info_llm_calls_total" in frame else "info_llm_calls"
        out["llm_calls_per_scenario"] = float(np.asarray(frame[calls], dtype=np.float64).mean())
    if "info_fallback" in frame:
        out["fallback_pct"] = float(100.0 * np.asarray(frame["info_fallback"], dtype=bool).mean())
    if "sumo_collision" in frame and len(frame):  # closed loop in SUMO: SUMO's own check beside the metric's
        out["sumo_cr_pct"] = float(100.0 * np.asarray(frame["sumo_collision"], dtype=bool).mean())
    if "n_replans" in frame and len(frame):  # closed loop
        out["replans_per_scenario"] = float(np.asarray(frame["n_replans"], dtype=np.float64).mean())
        out["sim_s"] = float(np.asarray(frame["sim_s"], dtype=np.float64).mean())
        if "nbr_reactive" in frame:  # neighbours SUMO drove (hand-overs), per scenario
            out["nbr_reactive_per_scenario"] = float(np.nanmean(np.asarray(frame["nbr_reactive"], dtype=np.float64)))
    for column, key in (("info_planner_cpu_ms_mean_over_replans", "planner_cpu_ms_per_replan"),
                        ("info_params_age_s_mean_over_replans", "llm_params_age_s"),
                        ("info_llm_in_force_mean_over_replans", "llm_in_force_pct")):
        if column in frame and len(frame):  # closed loop: planner CPU per scenario and replan; dual rate
            values = np.asarray(frame[column], dtype=np.float64)
            mean = float(np.nanmean(values)) if np.isfinite(values).any() else None
            out[key] = None if mean is None else (100.0 * mean if key.endswith("_pct") else mean)
    if "info_shielded" in frame:  # the LLM planners' safety shield replaced the plan
        out["shielded_pct"] = float(100.0 * np.asarray(frame["info_shielded"], dtype=np.float64).mean())
    if "info_consulted" in frame and len(frame):  # the decision step: the risk gate asked the model
        out["consulted_pct"] = float(100.0 * np.asarray(frame["info_consulted"], dtype=np.float64).mean())
    return out


def decision_shares(frames: Mapping[str, pd.DataFrame]) -> dict[str, dict[str, float]]:
    """Per deciding planner (per-scenario ``info_decision``), the share [%] of each decision."""
    out: dict[str, dict[str, float]] = {}
    for name, frame in frames.items():
        if "info_decision" in frame and len(frame):
            counts = frame["info_decision"].astype(str).value_counts()
            out[name] = {str(k): float(100.0 * v / len(frame)) for k, v in sorted(counts.items())}
    return out


#: rates of ``timing_summary`` that carry an interval: (key, per-scenario 0/1 column)
TIMING_RATES: Final = (("fallback_pct", "info_fallback"), ("sumo_cr_pct", "sumo_collision"),
                       ("shielded_pct", "info_shielded"), ("consulted_pct", "info_consulted"))


def planner_statistics(frame: pd.DataFrame, config: MetricsConfig | None = None) -> dict[str, Statistic]:
    """The per-scenario values behind every rate and mean of one planner's aggregate (its interval and
    paired comparisons use them): the metric keys and the rates of ``TIMING_RATES``. ``inference_s``
    averages the rows that really ran the model, as ``timing_summary``, and only when most rows were
    timed one by one: a batch planner's rows share their batch's mean time, whose spread says nothing."""
    if "inference_s" in frame:
        timed = np.where(_cached(frame), np.nan, np.asarray(frame["inference_s"], dtype=np.float64))
        live = timed[np.isfinite(timed)]
        frame = frame.assign(inference_s=timed) if 2 * len(np.unique(live)) > len(live) else frame.drop(
            columns="inference_s")
    out = metric_statistics(frame, config)
    for key, column in TIMING_RATES:
        if column in frame and len(frame):
            try:
                out[key] = rate_statistic(key, frame[column])
            except ValueError:  # not a 0/1 flag per scenario: no interval
                pass
    return out


def _paired_subject(frame: pd.DataFrame, reference: pd.DataFrame, config: MetricsConfig | None
                    ) -> tuple[dict[str, Statistic], dict[str, Statistic], np.ndarray]:
    mine, theirs = align(frame, reference)
    return planner_statistics(mine, config), planner_statistics(theirs, config), mine[GROUP_COLUMN].to_numpy()


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
                        reference: str | None) -> dict[str, Any]:
    """metrics.json's "intervals", "paired" (when there is a reference) and "statistics" of the planners'
    stored rows (``frames``, each with ``GROUP_COLUMN``)."""
    stats = {name: planner_statistics(f, config) for name, f in frames.items()}
    out: dict[str, Any] = {
        "intervals": intervals_of({name: (stats[name], f[GROUP_COLUMN].to_numpy()) for name, f in frames.items()})}
    if reference is not None and reference in frames:
        out["paired"] = {"reference": reference, "planners": paired_of(
            {name: _paired_subject(f, frames[reference], config) for name, f in frames.items() if name != reference})}
    keys: dict[str, Statistic] = {}
    for s in stats.values():
        keys.update({k: v for k, v in s.items() if k not in keys})
    out["statistics"] = {**statistics_record(keys=keys),
                         "n_vehicles": {name: n_groups(f[GROUP_COLUMN].to_numpy()) for name, f in frames.items()},
                         "design_effects": {name: design_effects(stats[name], f[GROUP_COLUMN].to_numpy())
                                            for name, f in frames.items()}}
    return out


def stored_vehicles(frame: pd.DataFrame) -> tuple[np.ndarray, int]:
    """(n,) ego vehicle of each stored row (its ``GROUP_COLUMN``) and how many rows lacked it (stored by
    an older letspi): those get the recording and ego id of their scenario id (``r01_v5_f100`` ->
    ``r01_v5``), exact within one recording, while recording ids can repeat across generated datasets."""
    ids = frame["scenario_id"].astype(str).str.rsplit("_f", n=1).str[0].to_numpy(dtype=object)
    if GROUP_COLUMN not in frame:
        return ids, len(frame)
    column = frame[GROUP_COLUMN]
    missing = column.isna().to_numpy()
    return np.where(missing, ids, column.astype(str).to_numpy(dtype=object)), int(missing.sum())


def read_summary(out_dir: Path) -> dict[str, Any]:
    """The contents of ``out_dir/metrics.json`` (FileNotFoundError naming it when absent)."""
    path = Path(out_dir) / "metrics.json"
    if not path.exists():
        raise FileNotFoundError(f"{path}: no metrics.json; is {out_dir} an evaluation directory?")
    data: dict[str, Any] = json.loads(path.read_text())
    return data


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


def _write_summary(out_dir: Path, record: dict[str, Any], results: dict[str, dict[str, AggValue]],
                   write_run_file: Callable[[], None], vehicles: np.ndarray, config: MetricsConfig,
                   reference: str | None = None, first: str | None = None) -> dict[str, dict[str, AggValue]]:
    """Merge ``results`` into metrics.json / metrics.md (planners of earlier runs kept), with the
    intervals and paired comparisons of every stored planner (``vehicles``: (B,) vehicle of each
    dataset row); returns all aggregates."""
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
    summary = uncertainty_summary(frames, config, choose_reference(list(frames), reference, first))
    payload = {"run": {"key": record["key"], **record["identity"], "dataset": record["dataset"]}, "planners": merged,
               **summary}
    decisions = decision_shares(frames)
    if decisions:
        payload["decisions"] = decisions
    atomic_write_text(metrics_file, json.dumps(payload, indent=2, allow_nan=False, default=float) + "\n")
    atomic_write_text(out_dir / "metrics.md", summary_markdown(payload) + "\n")
    return merged


def evaluate(
    planners: Sequence[BuiltPlanner],
    batch: ScenarioBatch,
    out_dir: Path,
    *,
    scenarios_file: str = "",
    config: MetricsConfig | None = None,
    mode: EvaluationMode = EvaluationMode.OPEN_LOOP,
    progress_factory: ProgressFactory | None = None,
    concurrency: int | None = None,
    on_run: Callable[[str, RunStats], None] | None = None,
    mode_settings: dict[str, Any] | None = None,
    runner: PlannerRunner | None = None,
    reference: str | None = None,
    workers: int = 0,
) -> dict[str, dict[str, AggValue]]:
    """Evaluate ``planners`` on ``batch``; write per-scenario parts, metrics.json and metrics.md.

    Returns ``{planner_name: aggregated metrics}`` (keys: ``letspi.metrics.aggregate`` and
    ``timing_summary``) for every planner stored in the directory (earlier runs included).
    ``concurrency``: scenarios in flight for per-scenario planners (None: each backend's default);
    ``on_run(name, stats)`` hears each such planner's throughput and latency. Raises
    ``ScenariosFailedError`` at the end if some planner left scenarios unstored (the others' metrics
    are written; rerun to complete). ``mode_settings`` joins the run's identity; ``runner`` replaces
    ``run_planner`` (closed-loop modes need one: use ``letspi.evaluation.closed_loop.evaluate_closed_loop``).
    ``reference``: the planner label every other is compared with in metrics.json's "paired" (default:
    ``sf`` when the directory has it, else the first of ``planners``; ``choose_reference``).
    ``workers`` > 1 (open loop, with the ``scenarios_file`` the batch was read from): the batch planners
    are scored in that many worker processes first (``store_in_workers``; same rows), then summarised here.
    """
    mode = EvaluationMode(mode)
    if mode.closed_loop and runner is None:
        raise ValueError(f"mode {mode!r} runs through letspi.evaluation.closed_loop.evaluate_closed_loop")
    config = config or MetricsConfig()
    out_dir = Path(out_dir)
    digests = scenario_digests(batch)
    record = run_record(batch, digests, scenarios_file, config, mode, mode_settings)
    run_pending = _check_run_file(out_dir, record)
    if reference is not None:  # refused before anything runs
        stored = read_summary(out_dir).get("planners", {}) if (out_dir / "metrics.json").exists() else {}
        choose_reference([*stored, *(b.name for b in planners if b.name not in stored)], reference)
    vehicles = vehicle_keys(batch)
    first_planner = planners[0].name if planners else None

    def write_run_file() -> None:  # with the first stored results: no run.json for a run that stored nothing
        nonlocal run_pending
        if run_pending:
            atomic_write_text(out_dir / "run.json", json.dumps(record, indent=2) + "\n")
            run_pending = False

    wrote_run_file = run_pending
    batch_planners = [b for b in planners if not runs_per_scenario(b.planner)]
    if workers > 1 and runner is None and scenarios_file and len(batch_planners) > 1:
        write_run_file()
        store_in_workers(batch_planners, scenarios_file, digests, out_dir, config, workers)
    results: dict[str, dict[str, AggValue]] = {}
    failures: list[ScenariosFailedError] = []
    for built in planners:
        progress = progress_factory(built.name, len(batch)) if progress_factory else None
        try:
            if runner is not None:
                frame, run = runner(built, batch, digests, out_dir, config, progress, write_run_file)
            else:
                frame, run = run_planner(built, batch, digests, out_dir, config, progress, concurrency=concurrency,
                                         before_write=write_run_file)
        except ScenariosFailedError as exc:
            if on_run is not None:
                on_run(built.name, exc.stats)
            failures.append(exc)
            continue
        except BaseException:
            # stopped (server down, disk full, Ctrl-C): the planners finished so far stay scored
            if results:
                _write_summary(out_dir, record, results, write_run_file, vehicles, config, reference, first_planner)
            elif wrote_run_file and not run_pending and not any(out_dir.glob("per_scenario/*/part-*.parquet")):
                (out_dir / "run.json").unlink(missing_ok=True)
            _remove_empty_dirs(out_dir / "per_scenario", out_dir)
            raise
        if on_run is not None and run is not None:
            on_run(built.name, run)
        timing = timing_summary(frame, built.load_s)
        agg = aggregate_metrics(frame, inference_time_s=live_inference_s(frame), config=config)
        results[built.name] = {**agg, **timing, "config_key": built.key}  # type: ignore[dict-item]
    merged = _write_summary(out_dir, record, results, write_run_file, vehicles, config, reference, first_planner)
    if failures:
        first = failures[0]
        message = str(first) if len(failures) == 1 else f"{len(failures)} planners left scenarios unstored; {first}"
        raise ScenariosFailedError(message, stats=first.stats)
    return merged
