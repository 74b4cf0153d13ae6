"""Resumable closed-loop output, one directory per run: ``run.json`` (a resume guard), per chunk ``traj-NNNNN.npz``
and ``part-NNNNN.parquet`` (one row per scenario), written atomically, the part last (its commit)."""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Callable, Sequence
from contextlib import closing
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from letspi.metrics.compute import ScenarioMetrics
from letspi.metrics.config import MetricsConfig
from letspi.metrics.registry import Agg, Metric
from letspi.planners.outputs import AS_NAMED, column, output, over_replans
from letspi.scenario.types import ScenarioBatch
from letspi.simulation.config import ClosedLoopConfig, EvaluationMode
from letspi.simulation.handover import hybrid_settings
from letspi.simulation.result import ClosedLoopChunk, chunk_metrics
from letspi.simulation.run import run_closed_loop
from letspi.simulation.spec import PlannerSpecLike, spec_name

_PART = re.compile(r"^(part|traj)-(\d{5})\.(parquet|npz)$")
_TRAJ_FIELDS = (
    "indices", "scenario_id", "ego_xy_m", "ego_vxy_mps", "nbr_xy_m", "nbr_vxy_mps", "nbr_valid", "nbr_lane_id",
    "nbr_handover_step", "replan_step", "plan_xy_m", "plan_goal_xy_m", "plan_nonfinite", "sumo_contact",
    "sumo_nbr_collisions", "plan_s", "sim_s", "cpu_s",
)  # fmt: skip


def _named(name: str, unit: str, dtype: str, doc: str, *aggregates: Agg) -> Metric:
    return Metric(name, unit, dtype, doc, AS_NAMED, tuple(aggregates))  # type: ignore[arg-type]


#: per-replan values the closed loop adds to every planner's outputs (stored at t = 0 and as the mean over replans)
REPLAN_OUTPUTS: tuple[Metric, ...] = (
    output("planner_cpu_ms", "ms", "float64", "CPU time of the replan per scenario (model calls included)"),
    output("llm_in_force", "bool", "float64", "dual rate: 1 once a model answer is in force"),
    output("params_age_s", "s", "float64", "dual rate: time since the parameters in force were asked for"),
    output("llm_answer_latency_s", "s", "float64", "dual rate: latency of an answer applied at this replan "
           "(NaN: none)"),
)
LLM_CALLS_TOTAL = output("llm_calls_total", "n", "float64", "model calls of all replans of the window",
                         Agg("llm_calls_per_scenario", "finite_mean", "model calls per scenario"))
#: what a closed-loop run stores beside the metrics and the planner's own outputs
CLOSED_LOOP_OUTPUTS: tuple[Metric, ...] = (
    *REPLAN_OUTPUTS,
    output("planner_cpu_ms" + "_mean_over_replans", "ms", "float64", "planner CPU per scenario and replan",
           Agg("planner_cpu_ms_per_replan", "finite_mean")),
    output("params_age_s" + "_mean_over_replans", "s", "float64", "dual rate: age of the parameters in force",
           Agg("llm_params_age_s", "finite_mean")),
    output("llm_in_force" + "_mean_over_replans", "1", "float64", "dual rate: share of replans with an answer in force",
           Agg("llm_in_force_pct", "pct_mean")),
    LLM_CALLS_TOTAL,
    _named("n_replans", "n", "int64", "replans of the window", Agg("replans_per_scenario", "finite_mean")),
    _named("sim_s", "s", "float64", "wall time of the window's simulation", Agg("sim_s", "finite_mean")),
    _named("cpu_s", "s", "float64", "CPU time of the window's simulation"),
    _named("nbr_reactive", "n", "int64", "neighbours the simulator drove (hand-overs)",
           Agg("nbr_reactive_per_scenario", "finite_mean")),
    _named("plan_nonfinite", "n", "int64", "replans whose plan was not finite"),
    _named("sumo_collision", "bool", "bool", "SUMO's own collision check (SUMO runs only)",
           Agg("sumo_cr_pct", "pct", "share of windows SUMO saw collide")),
    _named("sumo_collision_step", "step", "int64", "step of SUMO's first collision (-1 none)"),
    _named("sumo_nbr_collisions", "n", "int64", "collisions among the neighbours SUMO saw"),
)


class ClosedLoopStoreError(ValueError):
    """The directory holds another run (other planner, mode, replanning period or scenarios)."""


def scenario_fingerprint(scenario_ids: Sequence[str] | np.ndarray) -> str:
    h = hashlib.sha256()
    for sid in scenario_ids:
        h.update(str(sid).encode())
        h.update(b"\0")
    return h.hexdigest()[:16]


def chunk_frame(chunk: ClosedLoopChunk, metrics: ScenarioMetrics) -> pd.DataFrame:
    """One row per scenario of the chunk: metrics, SUMO collision columns (SUMO runs only), timings, plan extras."""
    frame = metrics.to_frame()
    frame.insert(0, "scenario_id", [str(s) for s in chunk.scenario_id])
    if chunk.simulator == "sumo":  # the replay runs no SUMO, so it has no SUMO collision check
        frame["sumo_collision"] = chunk.sumo_collision
        frame["sumo_collision_step"] = chunk.sumo_collision_step
        frame["sumo_nbr_collisions"] = chunk.sumo_nbr_collisions
    frame["plan_nonfinite"] = chunk.plan_nonfinite
    frame["nbr_reactive"] = (np.asarray(chunk.nbr_handover_step) >= 0).sum(axis=1)
    frame["n_replans"] = len(chunk.replan_step)
    frame["inference_s"] = chunk.plan_s
    frame["sim_s"] = chunk.sim_s
    frame["cpu_s"] = chunk.cpu_s
    for key, arr in chunk.plan_info.items():
        frame[column(key)] = arr[:, 0]  # the plan made at t = 0, as in open loop
        frame[over_replans(key)] = np.nanmean(arr, axis=1)
    return frame


class ClosedLoopStore:
    """One run's directory (see module doc)."""

    def __init__(self, directory: Path, record: dict[str, object]) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        run_file = self.directory / "run.json"
        if run_file.exists():
            old = json.loads(run_file.read_text())
            if old != record:
                raise ClosedLoopStoreError(f"{self.directory} holds another closed-loop run ({old}); this one is "
                                           f"{record}: use another directory or delete it")
        else:
            tmp = run_file.with_name("run.json.tmp")
            tmp.write_text(json.dumps(record, indent=2))
            os.replace(tmp, run_file)
        self.record = record

    @classmethod
    def for_run(
        cls, directory: Path, planner: str, mode: str, replan_s: float, batch: ScenarioBatch,
        mode_settings: dict[str, object] | None = None,
    ) -> ClosedLoopStore:
        """``mode_settings``: what else of the mode changes answers (``closed-loop-hybrid``: hand-over
        rule and scripted neighbours); absent from the record when None."""
        record: dict[str, object] = {"planner": planner, "mode": mode, "replan_s": round(float(replan_s), 6),
                                     "n_scenarios": len(batch), "fingerprint": scenario_fingerprint(batch.scenario_id)}
        if mode_settings:
            record["mode_settings"] = mode_settings
        return cls(directory, record)

    def _indices(self) -> list[int]:
        return sorted({int(m.group(2)) for p in self.directory.iterdir() if (m := _PART.match(p.name))})

    def parts(self) -> list[Path]:
        return sorted(self.directory.glob("part-*.parquet"))

    def done_ids(self) -> set[str]:
        done: set[str] = set()
        for part in self.parts():
            done.update(pd.read_parquet(part, columns=["scenario_id"])["scenario_id"].astype(str))
        return done

    def write(self, chunk: ClosedLoopChunk, frame: pd.DataFrame) -> Path:
        """Write a chunk's trajectories and rows (atomically, the rows last); returns the part path."""
        existing = self._indices()
        index = existing[-1] + 1 if existing else 0
        traj = self.directory / f"traj-{index:05d}.npz"
        arrays: dict[str, Any] = {name: np.asarray(getattr(chunk, name)) for name in _TRAJ_FIELDS}
        arrays["scenario_id"] = arrays["scenario_id"].astype(str)
        arrays.update({f"info__{k}": v for k, v in chunk.plan_info.items()})
        tmp = traj.with_name(traj.name + ".tmp.npz")
        np.savez_compressed(tmp, **arrays)
        os.replace(tmp, traj)
        part = self.directory / f"part-{index:05d}.parquet"
        tmp_part = part.with_name(part.name + ".tmp")
        frame.to_parquet(tmp_part, index=False)
        os.replace(tmp_part, part)
        return part

    def load_frame(self) -> pd.DataFrame:
        """Every committed row (each scenario once)."""
        parts = self.parts()
        if not parts:
            return pd.DataFrame()
        return pd.concat([pd.read_parquet(p) for p in parts], ignore_index=True)

    def load_chunks(self) -> ClosedLoopChunk:
        """All committed trajectories as one chunk (``indices`` refer to the run's batch)."""
        chunks = []
        for part in self.parts():
            with np.load(part.with_name(part.name.replace("part-", "traj-").replace(".parquet", ".npz"))) as z:
                info = {k[len("info__") :]: z[k] for k in z.files if k.startswith("info__")}
                arrays = {name: z[name] for name in _TRAJ_FIELDS if name in z.files}
                if "nbr_handover_step" not in arrays:  # written before hand-overs were recorded
                    arrays["nbr_handover_step"] = np.full(arrays["nbr_valid"].shape[:2], -1, dtype=np.int64)
                chunks.append(ClosedLoopChunk(planner=str(self.record["planner"]), mode=str(self.record["mode"]),
                                              replan_s=float(str(self.record["replan_s"])), plan_info=info, **arrays))
        if not chunks:
            raise FileNotFoundError(f"{self.directory} holds no closed-loop chunks yet")
        return ClosedLoopChunk.concat(chunks)


def run_closed_loop_to_dir(
    planner_spec: PlannerSpecLike,
    batch: ScenarioBatch,
    out_dir: Path,
    config: ClosedLoopConfig | None = None,
    *,
    metrics_config: MetricsConfig | None = None,
    progress: Callable[[int], None] | None = None,
    scripted_nbr: np.ndarray | None = None,
) -> pd.DataFrame:
    """Simulate and score every scenario of ``batch`` not yet in ``out_dir``; return all rows. Arguments as
    ``run_closed_loop``; ``progress(n)`` gets the scenarios done (first those of an earlier run)."""
    cfg = (config or ClosedLoopConfig()).for_planner(spec_name(planner_spec))
    settings = hybrid_settings(cfg, scripted_nbr) if cfg.mode is EvaluationMode.HYBRID else None
    store = ClosedLoopStore.for_run(out_dir, spec_name(planner_spec), cfg.mode.value, cfg.replan_s, batch, settings)
    done = store.done_ids()
    todo = np.flatnonzero([str(s) not in done for s in batch.scenario_id])
    if progress is not None and len(batch) - len(todo):
        progress(len(batch) - len(todo))
    if len(todo):
        with closing(run_closed_loop(planner_spec, batch, cfg, indices=todo, scripted_nbr=scripted_nbr)) as chunks:
            for chunk in chunks:
                store.write(chunk, chunk_frame(chunk, chunk_metrics(batch, chunk, metrics_config)))
                if progress is not None:
                    progress(len(chunk))
    return store.load_frame()
