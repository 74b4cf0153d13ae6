"""Closed loop in worker processes: same results as in-process, streamed chunks, resumable output,
killed workers and killed runs resume without losing or duplicating a scenario."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from test_simulation_support import FailingPlanner, as_built, generated_batch

from benchmarks.closed_loop import bench_closed_loop
from letspi.scenario.store import save_scenarios
from letspi.scenario.types import ScenarioBatch
from letspi.simulation import (
    ClosedLoopChunk,
    ClosedLoopConfig,
    ClosedLoopStore,
    ClosedLoopStoreError,
    ClosedLoopWorkerError,
    PlannerSpec,
    run_closed_loop,
    run_closed_loop_to_dir,
)

pytestmark = pytest.mark.sumo
SMALL_CHUNKS = ClosedLoopConfig(chunk_size=4, simulator="sumo")

RUN_SCRIPT = textwrap.dedent(
    """
    import sys
    from pathlib import Path

    from letspi.simulation import ClosedLoopConfig, PlannerSpec, run_closed_loop_to_dir
    from letspi.scenario.store import load_scenarios

    if __name__ == "__main__":
        batch = load_scenarios(Path(sys.argv[1]))
        config = ClosedLoopConfig(mode="closed-loop-reactive", workers=int(sys.argv[3]), chunk_size=4)
        frame = run_closed_loop_to_dir(PlannerSpec.of("idm"), batch, Path(sys.argv[2]), config)
        print("rows", len(frame))
    """
)


@pytest.fixture(scope="module")
def traffic(tmp_path_factory: pytest.TempPathFactory) -> ScenarioBatch:
    return generated_batch(tmp_path_factory.mktemp("cl_par_traffic"), n=32, seed=5)


@pytest.mark.slow  # over ~10 s on a loaded 2-core machine (notes/reliability.md)
def test_workers_give_the_in_process_result_each_scenario_once(traffic: ScenarioBatch) -> None:
    sub = traffic.take(np.arange(8))
    reactive = replace(SMALL_CHUNKS, mode="closed-loop-reactive")
    local = ClosedLoopChunk.concat(list(run_closed_loop(PlannerSpec.of("idm"), sub, reactive)))
    chunks = list(run_closed_loop(PlannerSpec.of("idm"), sub, replace(reactive, workers=2)))
    assert len(chunks) == 2 and all(len(c) == 4 for c in chunks)
    remote = ClosedLoopChunk.concat(chunks)
    assert sorted(remote.indices.tolist()) == list(range(8))
    a, b = local.take(np.argsort(local.indices)), remote.take(np.argsort(remote.indices))
    np.testing.assert_allclose(a.ego_xy_m, b.ego_xy_m, atol=1e-9)
    np.testing.assert_allclose(np.nan_to_num(a.nbr_xy_m), np.nan_to_num(b.nbr_xy_m), atol=1e-9)
    np.testing.assert_array_equal(a.sumo_contact, b.sumo_contact)


def test_a_failing_planner_in_a_worker_ends_the_run_with_its_traceback(traffic: ScenarioBatch) -> None:
    with pytest.raises(ClosedLoopWorkerError, match="planner bug for the test"):
        list(run_closed_loop(as_built(FailingPlanner()), traffic.take(np.arange(4)), ClosedLoopConfig(workers=1)))


def test_store_resumes_and_refuses_another_run(tmp_path: Path, traffic: ScenarioBatch) -> None:
    sub = traffic.take(np.arange(8))
    out = tmp_path / "run"
    first = run_closed_loop_to_dir(PlannerSpec.of("cv"), sub.take(np.arange(8)), out, SMALL_CHUNKS)
    assert len(first) == 8 and first["scenario_id"].is_unique
    assert {"collision", "sumo_collision", "ade_m", "inference_s", "cpu_s"} <= set(first.columns)
    parts = sorted(p.name for p in out.iterdir())
    again = run_closed_loop_to_dir(PlannerSpec.of("cv"), sub, out, SMALL_CHUNKS)
    assert sorted(p.name for p in out.iterdir()) == parts  # nothing simulated twice
    assert again["scenario_id"].tolist() == first["scenario_id"].tolist()
    traj = ClosedLoopStore.for_run(out, "cv", "closed-loop-log", 1.0, sub).load_chunks()
    assert traj.ego_xy_m.shape == (8, 125, 2) and traj.plan_xy_m.shape == (8, 5, 125, 2)
    with pytest.raises(ClosedLoopStoreError, match="another closed-loop run"):
        run_closed_loop_to_dir(PlannerSpec.of("cv"), sub, out, replace(SMALL_CHUNKS, mode="closed-loop-reactive"))


def _children(pid: int) -> list[int]:
    path = Path(f"/proc/{pid}/task/{pid}/children")
    return [int(c) for c in path.read_text().split()] if path.exists() else []


def _workers(pid: int) -> list[int]:
    out = []
    for child in _children(pid):
        cmd = Path(f"/proc/{child}/cmdline").read_bytes().replace(b"\0", b" ")
        if b"spawn_main" in cmd and b"resource_tracker" not in cmd:
            out.append(child)
    return out


def _start_run(tmp_path: Path, batch: ScenarioBatch, out: Path, workers: int) -> subprocess.Popen[str]:
    scen = tmp_path / "scenarios.arrow"
    save_scenarios(batch, scen)
    script = tmp_path / "run_cl.py"
    script.write_text(RUN_SCRIPT)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    return subprocess.Popen([sys.executable, str(script), str(scen), str(out), str(workers)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)


def _wait_for_parts(out: Path, proc: subprocess.Popen[str], n: int, timeout_s: float = 120.0) -> int:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        count = len(list(out.glob("part-*.parquet"))) if out.exists() else 0
        if count >= n:
            return count
        if proc.poll() is not None:
            raise AssertionError(f"run ended early: {proc.stderr.read() if proc.stderr else ''}")
        time.sleep(0.02)
    raise AssertionError("no chunk was written in time")


@pytest.mark.slow  # over ~10 s on a loaded 2-core machine (notes/reliability.md)
def test_a_killed_worker_is_replaced_and_no_scenario_is_lost_or_duplicated(
    tmp_path: Path, traffic: ScenarioBatch
) -> None:
    out = tmp_path / "run"
    proc = _start_run(tmp_path, traffic, out, workers=2)
    try:
        done_at_kill = _wait_for_parts(out, proc, 1)
        workers = _workers(proc.pid)
        assert len(workers) == 2
        os.kill(workers[0], signal.SIGKILL)
        _, err = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 0, err
    assert done_at_kill < 8  # 32 scenarios in chunks of 4: the kill came mid-run
    frame = ClosedLoopStore.for_run(out, "idm", "closed-loop-reactive", 1.0, traffic).load_frame()
    assert len(frame) == len(traffic) and frame["scenario_id"].is_unique
    assert set(frame["scenario_id"]) == {str(s) for s in traffic.scenario_id}


@pytest.mark.slow  # over ~10 s on a loaded 2-core machine (notes/reliability.md)
def test_a_killed_run_resumes_without_duplicates(tmp_path: Path, traffic: ScenarioBatch) -> None:
    out = tmp_path / "run"
    proc = _start_run(tmp_path, traffic, out, workers=2)
    try:
        _wait_for_parts(out, proc, 2)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the run and its workers, mid-run
        proc.wait(timeout=30)
    store = ClosedLoopStore.for_run(out, "idm", "closed-loop-reactive", 1.0, traffic)
    before = store.load_frame()
    assert 8 <= len(before) < len(traffic) and before["scenario_id"].is_unique
    seen: list[int] = []
    frame = run_closed_loop_to_dir(PlannerSpec.of("idm"), traffic, out,
                                   ClosedLoopConfig(mode="closed-loop-reactive", chunk_size=4), progress=seen.append)
    assert seen[0] == len(before)  # found on disk, not simulated again
    assert sum(seen) == len(traffic)
    assert len(frame) == len(traffic) and frame["scenario_id"].is_unique
    kept = frame.set_index("scenario_id").loc[before["scenario_id"], "min_ttc_s"].to_numpy()
    np.testing.assert_array_equal(kept, before["min_ttc_s"].to_numpy())


@pytest.mark.slow
def test_bench_reports_throughput_and_speedup(tmp_path: Path, traffic: ScenarioBatch) -> None:
    scen = tmp_path / "scenarios.arrow"
    save_scenarios(traffic.take(np.arange(8)), scen)
    out = bench_closed_loop(scenarios=scen, n=8, planner="idm", workers=2, chunk_size=4, n_reload=4)
    for key in ("in_process_scenarios_per_s", "workers_1_scenarios_per_s", "workers_2_scenarios_per_s",
                "speedup_2_workers_over_1", "lockstep_speedup_vs_reload_per_scenario", "sumo_load_ms"):
        assert isinstance(out[key], float) and out[key] > 0, key
    assert 0.0 <= out["collision_flags_agree_pct"] <= 100.0 and out["collisions_metric"] <= 8
