"""``python -m benchmarks.speed closed-loop``: closed-loop throughput per worker and the multi-worker speed-up.

Everything is measured in one process run, on the same scenarios:

* in-process (``workers=0``): scenarios/s, split into planner time and simulation time, CPU time,
  SUMO (re)load and network build times;
* lockstep vs one SUMO load per scenario (``chunk_size=1``): why scenarios share a network;
* ``workers=1`` and ``workers=N`` processes: wall time (worker start-up included) and the speed-up,
  plus the busy throughput of a worker (its chunks' own wall time, start-up excluded);
* collision flags of SUMO and of the metric code on these scenarios;
* in ``closed-loop-log``, the log replay without SUMO (``letspi.simulation.replay``) on the same
  scenarios in this process: its throughput, the speed-up over SUMO and the largest difference of
  the simulated ego positions.

Everything else runs in SUMO (``simulator="sumo"``), whatever the mode.

The machine's 1-minute load average is reported before and after: on a shared machine the
wall-clock numbers (and the speed-up) depend on it; ``*_cpu_s_*`` does not.
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from letspi.highd.io import read_recordings
from letspi.planners.options import DEFAULT_OPTIONS, PlannerOptions
from letspi.scenario.extract import extract_scenarios
from letspi.scenario.store import load_scenarios
from letspi.scenario.types import ScenarioBatch
from letspi.simulation import ClosedLoopChunk, ClosedLoopConfig, PlannerSpec, chunk_metrics, run_closed_loop
from letspi.simulation.spec import runs_dual_rate
from letspi.simulation.worker import ChunkWorker, make_tasks
from letspi.trafficgen.generate import generate_highd


def bench_scenarios(scenarios: Path | None, n: int, minutes: float, seed: int) -> ScenarioBatch:
    """The first ``n`` scenarios of a file, or of ``minutes`` of freshly generated traffic."""
    if scenarios is not None:
        batch = load_scenarios(scenarios)
    else:
        with tempfile.TemporaryDirectory(prefix="letspi-bench-cl-") as tmp:
            generate_highd(Path(tmp), minutes=minutes, seed=seed)
            batch = extract_scenarios(read_recordings(Path(tmp)))
    if len(batch) < n:
        raise ValueError(f"only {len(batch)} scenarios available, {n} requested (generate more minutes)")
    return batch.take(np.arange(n))


def _timed_run(spec: PlannerSpec, batch: ScenarioBatch, config: ClosedLoopConfig) -> tuple[float, ClosedLoopChunk]:
    t0 = time.perf_counter()
    chunks = list(run_closed_loop(spec, batch, config))
    return time.perf_counter() - t0, ClosedLoopChunk.concat(chunks)


def _in_process(spec: PlannerSpec, batch: ScenarioBatch, config: ClosedLoopConfig,
                out: dict[str, float | str]) -> ClosedLoopChunk:
    """In-process throughput, with the worker object itself to read SUMO's load and build times (into
    ``out``); returns the simulated chunk."""
    n = len(batch)
    cfg = config.for_planner(spec.name)
    worker = ChunkWorker(spec, cfg)
    try:
        tasks = make_tasks(batch, cfg)
        worker.run(make_tasks(batch.take(np.arange(min(4, n))), cfg)[0])  # warm-up: planner, network, SUMO
        loads0, load_s0 = worker.session.loads, worker.session.load_s
        t0, c0 = time.perf_counter(), time.process_time()
        local = ClosedLoopChunk.concat([worker.run(task) for task in tasks])
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        out["in_process_scenarios_per_s"] = n / wall
        out["in_process_plan_ms_per_scenario"] = 1e3 * float(local.plan_s.sum()) / n
        out["in_process_sim_ms_per_scenario"] = 1e3 * float(local.sim_s.sum()) / n
        out["in_process_cpu_ms_per_scenario"] = 1e3 * cpu / n
        out["sumo_load_ms"] = 1e3 * (worker.session.load_s - load_s0) / max(1, worker.session.loads - loads0)
        out["network_build_ms"] = 1e3 * worker.session.networks.build_s / max(1, worker.session.networks.builds)
    finally:
        worker.close()
    return local


def _workers(spec: PlannerSpec, batch: ScenarioBatch, workers: int, config: ClosedLoopConfig,
             out: dict[str, float | str]) -> None:
    """Throughput of 1 and of ``workers`` worker processes, and the speed-up (into ``out``)."""
    n = len(batch)
    wall_1, one = _timed_run(spec, batch, replace(config, workers=1))
    wall_n, many = _timed_run(spec, batch, replace(config, workers=workers))
    out["workers_1_wall_s"] = wall_1
    out["workers_1_scenarios_per_s"] = n / wall_1
    out["workers_1_busy_scenarios_per_s"] = n / float(one.plan_s.sum() + one.sim_s.sum())
    out[f"workers_{workers}_wall_s"] = wall_n
    out[f"workers_{workers}_scenarios_per_s"] = n / wall_n
    out[f"workers_{workers}_busy_scenarios_per_s_per_worker"] = n / float(many.plan_s.sum() + many.sim_s.sum())
    out[f"speedup_{workers}_workers_over_1"] = wall_1 / wall_n
    out["cpu_ms_per_scenario_in_workers"] = 1e3 * float(many.cpu_s.sum()) / n


def _replay(spec: PlannerSpec, batch: ScenarioBatch, config: ClosedLoopConfig, sumo: ClosedLoopChunk,
            out: dict[str, float | str]) -> None:
    """The log replay in this process on the same scenarios (into ``out``), against SUMO's ``sumo`` run."""
    n = len(batch)
    # the replay in its own chunks (its default, larger than SUMO's, unless the run set one)
    replay_cfg = replace(config, simulator="replay").for_planner(spec.name)
    worker = ChunkWorker(spec, replay_cfg)
    out["replay_chunk_size"] = float(replay_cfg.scenarios_per_chunk(worker.dual_rate))
    try:
        worker.run(make_tasks(batch.take(np.arange(min(4, n))), replay_cfg)[0])  # warm-up: the planner
        t0, c0 = time.perf_counter(), time.process_time()
        replay = ClosedLoopChunk.concat([worker.run(task) for task in make_tasks(batch, replay_cfg,
                                                                                  dual_rate=worker.dual_rate)])
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    finally:
        worker.close()
    replay = replay.take(np.argsort(replay.indices))
    sumo = sumo.take(np.argsort(sumo.indices))
    sumo_per_s = float(out["in_process_scenarios_per_s"])
    out["replay_scenarios_per_s"] = n / wall
    out["replay_plan_ms_per_scenario"] = 1e3 * float(replay.plan_s.sum()) / n
    out["replay_sim_ms_per_scenario"] = 1e3 * float(replay.sim_s.sum()) / n
    out["replay_cpu_ms_per_scenario"] = 1e3 * cpu / n
    out["replay_speedup_over_sumo"] = n / wall / sumo_per_s
    out["replay_max_ego_diff_m"] = float(np.nanmax(np.abs(replay.ego_xy_m - sumo.ego_xy_m)))


def bench_closed_loop(
    scenarios: Path | None = None,
    n: int = 256,
    planner: str = "sf",
    mode: str = "closed-loop-log",
    replan_s: float = 1.0,
    workers: int = 2,
    chunk_size: int | None = None,
    n_reload: int = 32,
    minutes: float = 3.0,
    seed: int = 0,
    options: PlannerOptions = DEFAULT_OPTIONS,
) -> dict[str, float | str]:
    """Measure closed-loop throughput (see module doc) of ``planner`` under ``options``; returns a flat dict of
    numbers."""
    if workers < 2:
        raise ValueError("workers must be >= 2 (the speed-up is measured against 1 worker)")
    batch = bench_scenarios(scenarios, n, minutes, seed)
    spec = PlannerSpec.of(planner, options)
    config = ClosedLoopConfig(mode=mode, replan_s=replan_s, chunk_size=chunk_size, simulator="sumo")  # type: ignore[arg-type]
    out: dict[str, float | str] = {
        "planner": planner, "mode": mode, "replan_s": replan_s, "n_scenarios": float(n),
        "chunk_size": float(config.scenarios_per_chunk(runs_dual_rate(spec))), "cpu_count": float(os.cpu_count() or 1),
        "load_avg_1min_start": os.getloadavg()[0],
    }  # fmt: skip

    local = _in_process(spec, batch, config, out)

    # one SUMO load and a batch-of-one planner call per scenario, on a subset
    m = min(n_reload, n)
    sub = batch.take(np.arange(m))
    wall_lock, _ = _timed_run(spec, sub, config)
    wall_one, _ = _timed_run(spec, sub, replace(config, chunk_size=1))
    out["reload_per_scenario_scenarios_per_s"] = m / wall_one
    out["lockstep_speedup_vs_reload_per_scenario"] = wall_one / wall_lock

    _workers(spec, batch, workers, config, out)

    metrics = chunk_metrics(batch, local)
    out["collisions_metric"] = float(metrics.collision.sum())
    out["collisions_sumo"] = float(local.sumo_collision.sum())
    out["collision_flags_agree_pct"] = 100.0 * float(np.mean(metrics.collision == local.sumo_collision))
    if config.mode.value == "closed-loop-log":
        _replay(spec, batch, config, local, out)
    out["load_avg_1min_end"] = os.getloadavg()[0]
    return out
