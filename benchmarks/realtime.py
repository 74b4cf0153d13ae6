"""``python -m benchmarks.speed closed-loop`` with an LLM planner: does dual-rate LetsPi run in real time?

Each of ``n`` scenarios (5 s after t = 0) is simulated alone (``chunk_size=1``), with its LLM calls,
by one in-process worker: the planner is built and the model loaded first (``build_s``), then
``warmup`` scenarios are simulated and not counted (first network, first prompt). Reported per
scenario: the wall time (target: at most the 5 s it simulates), CPU time of the process (the LLM's
threads included), LLM calls, the latency of the answers applied, when the first answer took effect,
how old the parameters in force were, and the physics CPU per replan (context, rollout, shield; this
thread only, the LLM calls not included).

With the measured latency (the default) the LLM runs in a background thread while the simulation
goes on, and simulated time waits for the wall clock while an answer is outstanding, so the wall
time is what a car would see. The machine's 1-minute load is reported before and after.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from benchmarks.closed_loop import bench_scenarios
from letspi.constants import DT_S, HORIZON_S
from letspi.planners.options import PlannerOptions
from letspi.simulation import ClosedLoopChunk, ClosedLoopConfig, PlannerSpec
from letspi.simulation.schedule import DualRateConfig
from letspi.simulation.worker import ChunkTask, ChunkWorker, make_tasks


def _finite_mean(values: np.ndarray) -> float:
    finite = np.asarray(values, dtype=np.float64)
    finite = finite[np.isfinite(finite)]
    return float(finite.mean()) if finite.size else float("nan")


def bench_real_time(
    scenarios: Path | None = None,
    n: int = 8,
    planner: str = "letspi-fast",
    options: PlannerOptions | None = None,
    mode: str = "closed-loop-log",
    replan_s: float = 0.2,
    dual_rate: DualRateConfig | None = None,
    warmup: int = 1,
    minutes: float = 3.0,
    seed: int = 0,
) -> dict[str, float | str]:
    """Wall time per 5 s closed-loop scenario of a dual-rate LLM planner (module docstring)."""
    if n < 1 or warmup < 0:
        raise ValueError(f"need n >= 1 and warmup >= 0, got {n}, {warmup}")
    dual = dual_rate or DualRateConfig()
    batch = bench_scenarios(scenarios, n + warmup, minutes, seed)
    spec = PlannerSpec.of(planner, options)
    config = ClosedLoopConfig(mode=mode, replan_s=replan_s, chunk_size=1, dual_rate=dual)  # type: ignore[arg-type]
    out: dict[str, float | str] = {
        "planner": planner, "mode": mode, "replan_s": replan_s, "llm_period_s": dual.llm_period_s,
        "llm_latency_s": "measured" if dual.measured else float(dual.llm_latency_s or 0.0),
        "n_scenarios": float(n), "warmup_scenarios": float(warmup), "cpu_count": float(os.cpu_count() or 1),
        "load_avg_1min_start": os.getloadavg()[0],
    }  # fmt: skip
    t0 = time.perf_counter()
    worker = ChunkWorker(spec, config)
    out["build_s"] = time.perf_counter() - t0
    try:
        if not worker.dual_rate:
            raise ValueError(f"{planner!r} is not an LLM planner (dual rate applies to letspi-fast, letspi-fs, llm, "
                             "letspi-memory); the throughput bench measures the others")
        walls, chunk = _simulate_alone(worker, make_tasks(batch, config), warmup)
    finally:
        worker.close()
    out.update(_summary(chunk, walls))
    out["load_avg_1min_end"] = os.getloadavg()[0]
    return out


def _simulate_alone(worker: ChunkWorker, tasks: list[ChunkTask], warmup: int) -> tuple[np.ndarray, ClosedLoopChunk]:
    """Wall time of each task after the first ``warmup`` (one scenario each) and their chunks."""
    for task in tasks[:warmup]:
        worker.run(task)
    walls: list[float] = []
    chunks: list[ClosedLoopChunk] = []
    for task in tasks[warmup:]:
        t0 = time.perf_counter()
        chunks.append(worker.run(task))
        walls.append(time.perf_counter() - t0)
    return np.asarray(walls), ClosedLoopChunk.concat(chunks)


def _summary(chunk: ClosedLoopChunk, wall: np.ndarray) -> dict[str, float | str]:
    """Per-scenario means of the measured scenarios (module docstring)."""
    info = chunk.plan_info
    latency = np.asarray(info["llm_answer_latency_s"], dtype=np.float64)
    in_force = np.nan_to_num(np.asarray(info["llm_in_force"], dtype=np.float64)) > 0.5
    steps = np.asarray(chunk.replan_step, dtype=np.float64)
    first = np.where(in_force.any(axis=1), steps[np.argmax(in_force, axis=1)] * DT_S, np.nan)
    return {
        "wall_s_per_scenario_mean": float(wall.mean()),
        "wall_s_per_scenario_max": float(wall.max()),
        "real_time_factor": float(wall.mean()) / HORIZON_S,  # <= 1: real time
        "cpu_s_per_scenario": float(np.asarray(chunk.cpu_s).mean()),
        "plan_s_per_scenario": float(np.asarray(chunk.plan_s).mean()),
        "sim_s_per_scenario": float(np.asarray(chunk.sim_s).mean()),
        "llm_calls_per_scenario": float(np.nansum(np.asarray(info["llm_calls"], dtype=np.float64), axis=1).mean()),
        "llm_answer_latency_s_mean": _finite_mean(latency),
        "llm_answer_latency_s_max": float(np.nanmax(latency)) if np.isfinite(latency).any() else float("nan"),
        "first_answer_in_force_s_mean": _finite_mean(first),
        "llm_in_force_pct": 100.0 * float(in_force.mean()),
        "params_age_s_mean": _finite_mean(info["params_age_s"]),
        "planner_cpu_ms_per_scenario_per_replan": _finite_mean(info["planner_cpu_ms"]),
        "shielded_pct_of_replans": 100.0 * _finite_mean(info["shielded"]) if "shielded" in info else float("nan"),
    }
