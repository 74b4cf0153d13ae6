"""Run planners over scenarios (open loop here; closed loop through a ``runner``), score and store their rows.

Planners that do not read the future see each batch's history only; metrics use the full batch. Per-scenario
planners keep ``concurrency`` scenarios in flight, written in scenario order (concurrency never changes results).
A planner's info must be declared by its kind (``PlannerKind.outputs``). ``inference_s``: wall time of ``plan``
per scenario [s]."""

from __future__ import annotations

import functools
import json
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from letspi.assembly.planners import BuiltPlanner
from letspi.assembly.planners import build_planner as assemble_planner
from letspi.evaluation.concurrent import plan_concurrently, planner_concurrency, runs_per_scenario
from letspi.evaluation.results import (
    PartWriter,
    ProgressCallback,
    check_run_file,
    load_planner_results,
    read_summary,
    remove_empty_dirs,
    run_record,
)
from letspi.evaluation.summary import choose_reference, known_outputs, live_inference_s, timing_summary, write_summary
from letspi.execution.interrupt import WorkerPool
from letspi.execution.ordered import RunnerConfig, RunStats, ScenariosFailedError
from letspi.fsutil import atomic_write_text
from letspi.metrics.aggregate import AggValue, aggregate_metrics
from letspi.metrics.compute import ScenarioMetrics, compute_metrics
from letspi.metrics.config import MetricsConfig
from letspi.metrics.registry import Metric
from letspi.metrics.uncertainty import GROUP_COLUMN
from letspi.planners.base import PlanBatch
from letspi.planners.outputs import by_column, info_columns
from letspi.scenario.identity import scenario_digests
from letspi.scenario.split import vehicle_keys
from letspi.scenario.store import load_scenarios
from letspi.scenario.types import ScenarioBatch
from letspi.simulation.config import EvaluationMode
from letspi.simulation.spec import PlannerSpec

ProgressFactory = Callable[[str, int], ProgressCallback]
#: A way to run one planner (open loop: ``run_planner``; closed loop: ``closed_loop.ClosedLoopRunner``):
#: (planner, batch, digests, out_dir, metrics config, progress, before_write) -> (its rows, run stats).
#: ``before_write()`` must run before each part is written (``PartWriter`` does).
PlannerRunner = Callable[[BuiltPlanner, ScenarioBatch, np.ndarray, Path, MetricsConfig, ProgressCallback | None,
                          Callable[[], None] | None], tuple[pd.DataFrame, RunStats | None]]


@dataclass(frozen=True)
class EvaluationSettings:
    """How ``evaluate`` runs. ``scenarios_file``: where the batch was read from (recorded; needed for
    ``workers`` > 1, which scores the batch planners in that many processes first). ``mode_settings``: what
    else of the mode changes answers (joins the run's identity). ``runner``: replaces ``run_planner``
    (closed loop: ``letspi.evaluation.closed_loop.evaluate_closed_loop``), ``mode_outputs`` its extra
    columns. ``reference``: the planner every other is compared with (default ``choose_reference``).
    ``concurrency``: scenarios in flight for per-scenario planners (None: the backend's default).
    ``progress_factory(name, total)`` and ``on_run(name, stats)`` report progress and throughput."""

    scenarios_file: str = ""
    metrics: MetricsConfig = field(default_factory=MetricsConfig)
    mode: EvaluationMode = EvaluationMode.OPEN_LOOP
    mode_settings: Mapping[str, Any] | None = None
    runner: PlannerRunner | None = None
    mode_outputs: tuple[Metric, ...] = ()
    reference: str | None = None
    concurrency: int | None = None
    workers: int = 0
    progress_factory: ProgressFactory | None = None
    on_run: Callable[[str, RunStats], None] | None = None


def _scored_frame(metrics: ScenarioMetrics, scenario_ids: np.ndarray, idx: np.ndarray, digests: np.ndarray,
                  vehicles: np.ndarray, info: dict[str, np.ndarray], inference_s: float | np.ndarray) -> pd.DataFrame:
    """The stored rows of scenarios ``idx``: ids, ego vehicle, metrics, planning time per scenario, plan info."""
    frame = metrics.to_frame()
    columns: dict[str, Any] = {"scenario_id": [str(s) for s in scenario_ids],
                               "scenario_digest": [str(d) for d in digests[idx]], "row": idx.astype(np.int64),
                               GROUP_COLUMN: [str(v) for v in vehicles[idx]]}
    tail: dict[str, Any] = {"inference_s": np.broadcast_to(np.asarray(inference_s, dtype=np.float64), (len(idx),)),
                            **info_columns(info)}
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
    """Plan and score every scenario of ``batch`` not yet stored for ``built`` (``PartWriter``); return all its
    rows and, for per-scenario planners, the run's ``RunStats`` (``concurrency``: None = the backend's default)."""
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

    def store(metrics: ScenarioMetrics, idx: np.ndarray, plan: PlanBatch, seconds: float | np.ndarray) -> Path:
        built.check_outputs(plan.info)
        frame = _scored_frame(metrics, batch.scenario_id[idx], idx, digests, vehicles, plan.info, seconds)
        return store_part(frame, plan.xy_m, plan.vxy_mps, plan.goals_xy_m)

    run: RunStats | None = None
    if runs_per_scenario(planner):
        run = plan_concurrently(
            planner, batch, [int(i) for i in todo], reads_future=built.reads_future,
            measure=lambda sub, plan: compute_metrics(sub, plan.xy_m, plan.vxy_mps, plan.goals_xy_m, config),
            write_part=store, runner=RunnerConfig(concurrency=planner_concurrency(planner, concurrency)),
            progress=progress)
    else:
        step = max(1, int(planner.batch_size))
        for start in range(0, len(todo), step):
            idx = todo[start : start + step]
            sub = batch.take(idx)
            seen = sub if built.reads_future else sub.history()
            t0 = time.perf_counter()
            plan = planner.plan(seen)
            elapsed_s = time.perf_counter() - t0
            store(compute_metrics(sub, plan.xy_m, plan.vxy_mps, plan.goals_xy_m, config), idx, plan,
                  elapsed_s / len(idx))
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
    """A worker's share of ``evaluate(..., workers=N)``: one planner's parts for ``digests`` (in that order)."""
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
    """Store the parts of batch ``planners`` in ``workers`` spawned processes, one planner per task (same rows)."""
    specs = [PlannerSpec.of_built(b) for b in planners]
    with WorkerPool(min(workers, len(specs))) as pool:
        futures = [pool.submit(_planner_parts, s, scenarios_file, [str(d) for d in digests], str(out_dir), config)
                   for s in specs]
        for future in futures:
            future.result()


class RunFile:
    """``run.json``, written with the first stored results: a run that stored nothing leaves none."""

    def __init__(self, out_dir: Path, record: dict[str, Any]) -> None:
        self.path = out_dir / "run.json"
        self.record = record
        self.pending = check_run_file(out_dir, record)
        self.created_here = self.pending

    def write(self) -> None:
        if self.pending:
            atomic_write_text(self.path, json.dumps(self.record, indent=2) + "\n")
            self.pending = False

    def remove_if_unused(self, out_dir: Path) -> None:
        """After a failure: drop a ``run.json`` this run wrote when no part was stored."""
        if self.created_here and not self.pending and not any(out_dir.glob("per_scenario/*/part-*.parquet")):
            self.path.unlink(missing_ok=True)


def evaluate(planners: Sequence[BuiltPlanner], batch: ScenarioBatch, out_dir: Path,
             settings: EvaluationSettings | None = None) -> dict[str, dict[str, AggValue]]:
    """Evaluate ``planners`` on ``batch`` into ``out_dir``; returns ``{planner: aggregates}`` for every planner
    stored there (earlier runs included). Raises ``ScenariosFailedError`` at the end if some planner left
    scenarios unstored (the others' summaries are written; rerun to complete)."""
    s = settings or EvaluationSettings()
    mode = EvaluationMode(s.mode)
    if mode.closed_loop and s.runner is None:
        raise ValueError(f"mode {mode!r} runs through letspi.evaluation.closed_loop.evaluate_closed_loop")
    out_dir = Path(out_dir)
    digests = scenario_digests(batch)
    run_file = RunFile(out_dir, run_record(batch, digests, s.scenarios_file, s.metrics, mode,
                                           dict(s.mode_settings) if s.mode_settings else None))
    if s.reference is not None:  # refused before anything runs
        stored = read_summary(out_dir).get("planners", {}) if (out_dir / "metrics.json").exists() else {}
        choose_reference([*stored, *(b.name for b in planners if b.name not in stored)], s.reference)
    first = planners[0].name if planners else None
    known = known_outputs([*(o for b in planners for o in b.outputs), *s.mode_outputs])

    def summarise(results: dict[str, dict[str, AggValue]]) -> dict[str, dict[str, AggValue]]:
        return write_summary(out_dir, run_file.record, results, run_file.write, vehicle_keys(batch), s.metrics,
                             s.reference, first, known)

    batch_planners = [b for b in planners if not runs_per_scenario(b.planner)]
    if s.workers > 1 and s.runner is None and s.scenarios_file and len(batch_planners) > 1:
        run_file.write()
        store_in_workers(batch_planners, s.scenarios_file, digests, out_dir, s.metrics, s.workers)
    results: dict[str, dict[str, AggValue]] = {}
    failures: list[ScenariosFailedError] = []
    for built in planners:
        try:
            frame, run = _run_one(built, batch, digests, out_dir, s, run_file)
        except ScenariosFailedError as exc:
            if s.on_run is not None:
                s.on_run(built.name, exc.stats)
            failures.append(exc)
            continue
        except BaseException:  # stopped (server down, disk full, Ctrl-C): finished planners stay scored
            if results:
                summarise(results)
            else:
                run_file.remove_if_unused(out_dir)
            remove_empty_dirs(out_dir / "per_scenario", out_dir)
            raise
        if s.on_run is not None and run is not None:
            s.on_run(built.name, run)
        outputs = by_column((*built.outputs, *s.mode_outputs))
        timing = timing_summary(frame, built.load_s, outputs, s.metrics)
        agg = aggregate_metrics(frame, inference_time_s=live_inference_s(frame), config=s.metrics)
        results[built.name] = {**agg, **timing, "config_key": built.key}  # type: ignore[dict-item]
    merged = summarise(results)
    if failures:
        message = str(failures[0]) if len(failures) == 1 else (f"{len(failures)} planners left scenarios unstored; "
                                                              f"{failures[0]}")
        raise ScenariosFailedError(message, stats=failures[0].stats)
    return merged


def _run_one(built: BuiltPlanner, batch: ScenarioBatch, digests: np.ndarray, out_dir: Path, s: EvaluationSettings,
             run_file: RunFile) -> tuple[pd.DataFrame, RunStats | None]:
    progress = s.progress_factory(built.name, len(batch)) if s.progress_factory else None
    if s.runner is not None:
        return s.runner(built, batch, digests, out_dir, s.metrics, progress, run_file.write)
    return run_planner(built, batch, digests, out_dir, s.metrics, progress, concurrency=s.concurrency,
                       before_write=run_file.write)
