"""Closed-loop modes of ``letspi evaluate``: ``harness.evaluate`` with a ``ClosedLoopRunner`` into the same
directory. ``run.json``'s identity adds the mode and ``mode_settings``, each planner's key ``planner_evaluation``;
rows are scored on the simulated trajectories (the plan columns hold the simulated ego; the ``cl_*`` columns what the
closed-loop panel draws)."""

from __future__ import annotations

import importlib.util
import os
import shutil
import sys
from collections.abc import Callable, Mapping
from contextlib import closing
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from letspi.assembly.planners import BuiltPlanner
from letspi.constants import N_FUTURE
from letspi.evaluation.harness import EvaluationSettings, ProgressFactory, evaluate
from letspi.evaluation.results import PartWriter, ProgressCallback, load_planner_results
from letspi.execution.ordered import RunStats
from letspi.metrics.aggregate import AggValue
from letspi.metrics.compute import ScenarioMetrics
from letspi.metrics.config import MetricsConfig
from letspi.metrics.uncertainty import GROUP_COLUMN
from letspi.planners.llm import LLM_CACHED, LLM_CALLS
from letspi.planners.outputs import column
from letspi.scenario.scripted import recording_events, scripted_neighbours
from letspi.scenario.split import vehicle_keys
from letspi.scenario.store import read_scenario_meta
from letspi.scenario.types import ScenarioBatch
from letspi.simulation import ClosedLoopChunk, ClosedLoopConfig, PlannerSpec, chunk_metrics, run_closed_loop
from letspi.simulation.config import EvaluationMode
from letspi.simulation.handover import hybrid_settings
from letspi.simulation.schedule import ReleasingPlanner
from letspi.simulation.spec import PlannerSpecLike
from letspi.simulation.store import CLOSED_LOOP_OUTPUTS, LLM_CALLS_TOTAL, chunk_frame
from letspi.trafficgen.binaries import sumo_home

#: closed-loop per-scenario array columns (flat float32 in the parts; shapes per row)
CL_PLAN_XY = "cl_plan_xy_m"  # (R, F, 2) every plan, in the scenario's ego frame at t = 0
CL_PLAN_GOAL = "cl_plan_goal_xy_m"  # (R, 2)
CL_REPLAN_STEP = "cl_replan_step"  # (R,) frames after t = 0 at which each plan was made
CL_NBR_XY = "cl_nbr_xy_m"  # (N, F, 2) simulated (or replayed) neighbours, NaN when absent
CL_NBR_VALID = "cl_nbr_valid"  # (N, F) 1.0 / 0.0


class ClosedLoopSetupError(ValueError):
    """A closed-loop option cannot be honoured here (Ray or sumo-gui missing, bad period)."""


def mode_settings(config: ClosedLoopConfig, scripted_nbr: np.ndarray | None = None) -> dict[str, Any]:
    """What of the simulation changes answers (``run.json``): road and sublane model; the driver model where SUMO
    drives neighbours; in ``closed-loop-hybrid`` the hand-over rule and scripted neighbours (count and digest);
    ``simulator: replay`` for the replay (absent with SUMO). Not the workers, the chunk size or the GUI."""
    out: dict[str, Any] = {"lateral_resolution_m": config.lateral_resolution_m,
                           "road_behind_m": config.road_behind_m, "road_ahead_m": config.road_ahead_m}
    if config.mode.has_drivers:
        out["driver"] = {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(config.driver).items()}
    if config.mode is EvaluationMode.HYBRID:
        out.update(hybrid_settings(config, scripted_nbr))
    if not config.uses_sumo:
        out["simulator"] = "replay"
    return out


def planner_evaluation(config: ClosedLoopConfig, built: BuiltPlanner) -> dict[str, Any]:
    """What joins a planner's key: the mode and its replanning period; for a dual-rate planner also its LLM
    period and fixed latency (or ``measured``), and for one that holds presets the release mode."""
    out: dict[str, Any] = {"mode": config.mode.value, "replan_s": round(config.replan_s_of(built.name), 6)}
    if built.dual_rate:
        releasing = isinstance(built.planner, ReleasingPlanner) and built.planner.holds_presets
        out["dual_rate"] = config.dual_rate.identity(releasing)
    return out


@dataclass(frozen=True)
class ScriptedNeighbours:
    """Scripted neighbours of a batch (hybrid): ``mask`` (B, N) bool, slots that keep their log; ``source``, the
    HighD directory read (or None); ``matched``, scenarios whose recording has an events file there."""

    mask: np.ndarray
    source: Path | None
    matched: int

    def describe(self) -> str:
        if self.source is None:
            return "scripted events: none (no events directory; every neighbour follows the hand-over rule)"
        return (f"scripted events from {self.source}: {self.matched} scenarios of their recordings, "
                f"{int(self.mask.sum())} scripted neighbour slots in {int(self.mask.any(axis=1).sum())} scenarios")


def events_directory(scenarios_file: Path | None) -> Path | None:
    """The HighD directory a scenario file was cut from (its provenance ``source``), if it still exists:
    as recorded (relative paths from the current directory), else relative to the file's directory."""
    if scenarios_file is None:
        return None
    try:
        provenance = read_scenario_meta(Path(scenarios_file)).get("provenance")
    except (ValueError, OSError):
        return None
    source = provenance.get("source") if isinstance(provenance, dict) else None
    if not source:
        return None
    for candidate in (Path(str(source)), Path(scenarios_file).parent / str(source)):
        if candidate.is_dir():
            return candidate
    return None


def scripted_for(batch: ScenarioBatch, events_dir: Path | None, *, required: bool = True) -> ScriptedNeighbours:
    """Scripted neighbours of ``batch`` from the ``NN_events.csv`` of ``events_dir`` (None: none). Raises
    ``ClosedLoopSetupError`` when ``required`` and no events file matches the batch's recordings (else: none)."""
    none = ScriptedNeighbours(np.zeros(batch.nbr_id.shape, dtype=bool), None, 0)
    if events_dir is None:
        return none
    if not Path(events_dir).is_dir():
        raise ClosedLoopSetupError(f"--events {events_dir}: not a directory")
    events = recording_events(Path(events_dir))
    keys = np.asarray(batch.recording_key).astype(str)
    matched = int(np.isin(keys, list(events)).sum())
    if matched == 0 and not required:
        return none
    if matched == 0:
        raise ClosedLoopSetupError(f"--events {events_dir}: no NN_events.csv of the scenarios' recordings there "
                                   f"({len(events)} recordings with events, none of the {len(np.unique(keys))} "
                                   "the scenarios were cut from); pass the directory the scenarios came from, "
                                   "or --events none")
    return ScriptedNeighbours(scripted_neighbours(batch, events), Path(events_dir), matched)


def check_setup(settings: ClosedLoopConfig) -> None:
    """Fail early, in one line, when Ray or sumo-gui is asked for but not installed."""
    if settings.ray_address is not None and importlib.util.find_spec("ray") is None:
        raise ClosedLoopSetupError("--ray needs the optional extra 'ray': pip install 'letspi[ray]'")
    if settings.sumo_gui:
        if settings.uses_processes():
            raise ClosedLoopSetupError("--sumo-gui runs in this process: drop --workers/--ray")
        if not (sumo_home() / "bin" / "sumo-gui").is_file() and shutil.which("sumo-gui") is None:
            raise ClosedLoopSetupError("--sumo-gui needs SUMO's sumo-gui: install SUMO (e.g. apt-get install "
                                       "sumo-gui) and set SUMO_HOME")
        if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            raise ClosedLoopSetupError("--sumo-gui needs a display (DISPLAY is not set): run it on a desktop or "
                                       "with X forwarding (ssh -X)")


def part_frame(chunk: ClosedLoopChunk, metrics: ScenarioMetrics, digests: np.ndarray,
               vehicles: np.ndarray) -> pd.DataFrame:
    """The harness's row layout (id, digest, row, vehicle, metrics, ``inference_s``, info) plus ``chunk_frame``'s
    closed-loop columns. ``digests``, ``vehicles``: (B,) of the evaluated batch."""
    idx = np.asarray(chunk.indices, dtype=np.int64)
    frame = chunk_frame(chunk, metrics)
    frame.insert(1, "scenario_digest", [str(d) for d in digests[idx]])
    frame.insert(2, "row", idx)
    frame.insert(3, GROUP_COLUMN, [str(v) for v in vehicles[idx]])
    if LLM_CALLS.name in chunk.plan_info:  # model calls of all replans (``LLM_CALLS``: the t = 0 plan's)
        calls = np.asarray(chunk.plan_info[LLM_CALLS.name], dtype=np.float64)
        frame[column(LLM_CALLS_TOTAL)] = np.nansum(calls, axis=1)
    if LLM_CACHED.name in chunk.plan_info:  # a row's time is "cached" only if no replan called the model
        cached = np.asarray(chunk.plan_info[LLM_CACHED.name], dtype=np.float64)
        frame[column(LLM_CACHED)] = np.all(np.nan_to_num(cached, nan=1.0) > 0.5, axis=1)
    return frame


def trajectory_arrays(chunk: ClosedLoopChunk) -> dict[str, np.ndarray]:
    """The ``cl_*`` columns of a chunk (see the module docstring)."""
    k = len(chunk)
    return {
        CL_PLAN_XY: np.asarray(chunk.plan_xy_m),
        CL_PLAN_GOAL: np.asarray(chunk.plan_goal_xy_m),
        CL_REPLAN_STEP: np.broadcast_to(np.asarray(chunk.replan_step, dtype=np.float64), (k, len(chunk.replan_step))),
        CL_NBR_XY: np.asarray(chunk.nbr_xy_m),
        CL_NBR_VALID: np.asarray(chunk.nbr_valid, dtype=np.float32),
    }


@dataclass(frozen=True)
class ClosedLoopRow:
    """What the closed-loop panel needs of one stored scenario (ego frame at t = 0; R plans, N slots)."""

    ego_xy_m: np.ndarray  # (F, 2) simulated ego
    plans_xy_m: np.ndarray  # (R, F, 2)
    plan_goals_xy_m: np.ndarray  # (R, 2)
    replan_step: np.ndarray  # (R,) int
    nbr_xy_m: np.ndarray  # (N, F, 2)
    nbr_valid: np.ndarray  # (N, F) bool


def closed_loop_row(record: Mapping[Any, Any]) -> ClosedLoopRow:
    """A stored row (``load_planner_results(..., with_plans=True)``) as arrays."""
    steps = np.asarray(record[CL_REPLAN_STEP], dtype=np.float64).astype(np.int64)
    r = len(steps)
    valid = np.asarray(record[CL_NBR_VALID], dtype=np.float32) > 0.5
    n = len(valid) // N_FUTURE
    return ClosedLoopRow(
        ego_xy_m=np.asarray(record["plan_xy_m"], np.float64).reshape(N_FUTURE, 2),
        plans_xy_m=np.asarray(record[CL_PLAN_XY], np.float64).reshape(r, N_FUTURE, 2),
        plan_goals_xy_m=np.asarray(record[CL_PLAN_GOAL], np.float64).reshape(r, 2),
        replan_step=steps,
        nbr_xy_m=np.asarray(record[CL_NBR_XY], np.float64).reshape(n, N_FUTURE, 2),
        nbr_valid=valid.reshape(n, N_FUTURE),
    )


def closed_loop_rows(out_dir: Path, planner_name: str) -> dict[str, ClosedLoopRow]:
    """Every stored closed-loop row of one planner: scenario digest -> ``ClosedLoopRow``."""
    frame = load_planner_results(out_dir, planner_name, with_plans=True)
    if len(frame) and CL_PLAN_XY not in frame:
        raise ValueError(f"{out_dir}: {planner_name!r} has no closed-loop rows (an open-loop directory?)")
    return {str(rec["scenario_digest"]): closed_loop_row(rec) for rec in frame.to_dict("records")}


def planner_spec(built: BuiltPlanner, settings: ClosedLoopConfig) -> PlannerSpecLike:
    """The built planner in this process (its model loaded once); its configuration for workers or Ray."""
    if settings.uses_processes():
        return PlannerSpec.of_built(built)
    return built


@dataclass
class ClosedLoopRunner:
    """``harness.PlannerRunner`` of the closed-loop modes. ``scripted_nbr``: (B, N) bool, hybrid's log-keepers."""

    settings: ClosedLoopConfig
    scripted_nbr: np.ndarray | None = None

    def __call__(self, built: BuiltPlanner, batch: ScenarioBatch, digests: np.ndarray, out_dir: Path,
                 config: MetricsConfig, progress: ProgressCallback | None,
                 before_write: Callable[[], None] | None = None) -> tuple[pd.DataFrame, RunStats | None]:
        settings = self.settings
        writer = PartWriter(out_dir, built, planner_evaluation(settings, built), before_write)
        todo = writer.todo(digests, progress)
        if len(todo):
            vehicles = vehicle_keys(batch)
            try:
                # closing: stopped mid-chunk (Ctrl-C), the workers stop now, not when the generator is collected
                with closing(run_closed_loop(planner_spec(built, settings), batch, settings, indices=todo,
                                             scripted_nbr=self.scripted_nbr)) as chunks:
                    for chunk in chunks:
                        metrics = chunk_metrics(batch, chunk, config)
                        goals = (chunk.plan_goal_xy_m[:, 0] if chunk.plan_goal_xy_m.shape[1]
                                 else np.full((len(chunk), 2), np.nan))
                        writer.write(part_frame(chunk, metrics, digests, vehicles), chunk.ego_xy_m,
                                     chunk.ego_vxy_mps, goals, trajectory_arrays(chunk))
                        if progress is not None:
                            progress(len(chunk), None)
            except BaseException:
                writer.abandon()
                raise
        return load_planner_results(out_dir, built.name, digests=digests), None


def evaluate_closed_loop(
    planners: list[BuiltPlanner],
    batch: ScenarioBatch,
    out_dir: Path,
    settings: ClosedLoopConfig,
    *,
    scenarios_file: str = "",
    config: MetricsConfig | None = None,
    progress_factory: ProgressFactory | None = None,
    scripted_nbr: np.ndarray | None = None,
    reference: str | None = None,
) -> dict[str, dict[str, AggValue]]:
    """``harness.evaluate`` in a closed-loop mode. scripted_nbr: (B, N) bool over ``batch``, neighbours
    that keep their recorded behaviour in ``closed-loop-hybrid`` (``scripted_for``); else ignored."""
    check_setup(settings)
    unknown = sorted(set(settings.planner_replan_s) - {b.name for b in planners})
    if unknown:
        raise ClosedLoopSetupError(f"--replan-s for unknown planner label(s): {', '.join(unknown)}")
    if settings.mode is not EvaluationMode.HYBRID:
        scripted_nbr = None
    return evaluate(planners, batch, Path(out_dir), EvaluationSettings(
        scenarios_file=scenarios_file, metrics=config or MetricsConfig(), mode=settings.mode,
        mode_settings=mode_settings(settings, scripted_nbr), runner=ClosedLoopRunner(settings, scripted_nbr),
        mode_outputs=CLOSED_LOOP_OUTPUTS, reference=reference, progress_factory=progress_factory))
