"""Benchmark: scenarios per second with N scenarios in flight against OpenAI-compatible servers.

``bench_concurrency()`` measures, for each concurrency N:

* **concurrency** (the headline): against ``benchmarks.llm_server`` in its own process, answering
  every request after an injected latency (mean ``server_latency_ms``, spread +-``jitter``, many
  slots). A scenario here is the fast phase's LLM step: render the fast prompt (three memory
  examples) for one scene, send it, parse and validate the reply, and hand it to the runner's
  in-order writer. ``client_overhead_ms_per_request`` is the wall time a worker spends per request
  beyond the server's injected latency (the injected latencies are known exactly: they are a
  function of each request), ``client_cpu_ms_per_request`` the process CPU time per request.
* **pipeline**: the whole ``letspi-fast`` planner through ``letspi.evaluation.evaluate`` (goal
  prediction, retrieval, prompt, request, social force rollout, shield, metrics, part files) against
  the same server: what a real run gets, bounded by the client's CPU once the server is fast enough.
  ``physics_cpu_ms_per_scenario``: the CPU time of the batched physics per scenario (goals and
  neighbour prediction per block, rollout, shield and metrics per part; target <= 3 ms).
* **projection**: the pipeline with N = 64 against the test server with 64 slots answering in
  1 s, on ``projection_scenarios`` scenarios; the measured rate gives the time of a 10,000-scenario
  fast-phase run, next to the two bounds it sits between (64 requests/s from the server, and
  1 / client CPU per scenario).
* **real_server**: the same request step against llama-cpp-python's OpenAI-compatible server
  (``python -m llama_cpp.server``) with the embedded SmolLM2, at ``real_levels``, and its prefix
  reuse: the server logs how many prompt tokens each request evaluated after reusing the previous
  request's prefix (``Llama.generate: N prefix-match hit, remaining M prompt tokens to eval``).
"""

from __future__ import annotations

import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import httpx
import numpy as np

import letspi
from benchmarks.llm_server import latency_for, request_keys
from letspi.assembly.build import Builder
from letspi.assembly.planners import build_planners
from letspi.assembly.resolve import Resolver
from letspi.evaluation.harness import EvaluationSettings, evaluate
from letspi.execution.interrupt import CHILD_GRACE_S, received
from letspi.execution.ordered import RunnerConfig, RunStats, run_ordered
from letspi.llm.client import ParamAdvisor, RetryPolicy
from letspi.llm.describe import ScenarioDescription, describe_scenario
from letspi.llm.models import locate_model
from letspi.llm.prompts import MemoryExample, render_fast_prompt, render_physics_prompt
from letspi.llm.schema import PlannerReply
from letspi.method.memory import MemoryBank
from letspi.method.phases import collect
from letspi.planners.options import DEFAULT_OPTIONS
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import ScenarioBatch, concat_batches

TARGETS = {"speedup_16": 12.0, "speedup_64": 40.0, "client_overhead_ms": 5.0, "projection_s": 240.0,
           "physics_cpu_ms": 3.0}
_PREFIX_RE = re.compile(r"Llama\.generate: (\d+) prefix-match hit, remaining (\d+) prompt tokens to eval")
_MEMORIES = [
    MemoryExample("2 vehicles near, ego 30.0 m/s, keeping lane, nearest 15.0 m", PlannerReply(
        tau_s=1.5, k_np=45.0, k_nf=5.0, k_nl=1.0, k_boundary=1.0, k_cline=0.5, lon_factor=0.9, lane_factor=0.0),
        "min TTC 4.1 s, min in-path gap 9.5 m"),
    MemoryExample("0 vehicles near, ego 30.0 m/s, keeping lane, nearest 80.0 m", PlannerReply(
        tau_s=0.8, k_np=20.0, k_nf=4.0, k_nl=0.5, k_boundary=1.0, k_cline=0.5, lon_factor=0.3, lane_factor=0.0),
        "min TTC none s, min in-path gap 70.2 m"),
    MemoryExample("1 vehicles near, ego 28.0 m/s, keeping lane, nearest 3.0 m", PlannerReply(
        tau_s=1.0, k_np=25.0, k_nf=5.0, k_nl=3.0, k_boundary=1.5, k_cline=1.0, lon_factor=0.4, lane_factor=0.0),
        "min TTC 6.0 s, min in-path gap 30.1 m"),
]


def bench_batch(n: int, seed: int = 0) -> ScenarioBatch:
    """``n`` different three-lane scenes (a leader, a vehicle in the next lane, speeds drawn at random)."""
    rng = np.random.default_rng(seed)
    return concat_batches([
        straight_road_scenario(
            ego_speed_mps=float(rng.uniform(22.0, 36.0)),
            neighbours=[VehicleSpec(x0_m=float(rng.uniform(10.0, 90.0)), speed_mps=float(rng.uniform(15.0, 34.0))),
                        VehicleSpec(x0_m=float(rng.uniform(-40.0, 40.0)), speed_mps=float(rng.uniform(20.0, 36.0)),
                                    lane_offset=int(rng.choice([-1, 1])))],
            scenario_id=f"bench{i:05d}")
        for i in range(n)
    ])


def _descriptions(batch: ScenarioBatch) -> list[ScenarioDescription]:
    return [describe_scenario(batch.take([i]), (150.0, 0.0)) for i in range(len(batch))]


def _child_env() -> dict[str, str]:
    """The environment of a child process that must import this very letspi."""
    src = str(Path(letspi.__file__).resolve().parents[1])
    return {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (src, os.environ.get("PYTHONPATH")) if p)}


class _Process:
    """A server in a child process (terminated on exit)."""

    def __init__(self, args: list[str], *, log: Path | None = None) -> None:
        """Without ``log`` stdout is a pipe (the first line says the port); with it both streams go there."""
        self._log = open(log, "wb") if log is not None else None  # closed in close()
        out = self._log if self._log is not None else subprocess.PIPE
        err = out if self._log is not None else subprocess.DEVNULL
        self.proc = subprocess.Popen(args, env=_child_env(), stdout=out, stderr=err)

    def close(self) -> None:
        self.proc.terminate()
        try:  # after Ctrl-C a server finishing its request in flight is not waited for
            self.proc.wait(timeout=20 if received() is None else CHILD_GRACE_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        if self._log is not None:
            self._log.close()


def start_test_server(latency_ms: float, jitter: float, slots: int = 0) -> tuple[_Process, str]:
    """``benchmarks.llm_server`` in its own process; returns it and its base URL."""
    server = _Process([sys.executable, "-m", "benchmarks.llm_server", "--port", "0", "--latency-ms",
                       str(latency_ms), "--jitter", str(jitter), "--slots", str(slots)])
    assert server.proc.stdout is not None
    line = server.proc.stdout.readline().decode()
    if not line.startswith("listening on "):
        server.close()
        raise RuntimeError(f"the test server did not start (said {line!r})")
    return server, f"http://127.0.0.1:{int(line.split()[-1])}/v1"


def _advisor(spec: str, timeout_s: float = RetryPolicy.timeout_s) -> ParamAdvisor:
    return ParamAdvisor(spec, cache=None, retry=RetryPolicy(timeout_s=timeout_s))


def request_level(spec: str, descs: Sequence[ScenarioDescription], concurrency: int, n: int, *,
                  latency_s: float | None = None, jitter: float = 0.0, timeout_s: float = RetryPolicy.timeout_s,
                  warmup: int = 3) -> dict[str, Any]:
    """``n`` fast-phase LLM steps, ``concurrency`` in flight, through the runner (module docstring),
    after ``warmup`` untimed ones. ``latency_s`` / ``jitter``: the test server's injection, to compute
    the client overhead: per request (``client_overhead_ms_per_request``: N x wall time minus the
    injected latencies, over the requests; ``client_overhead_ms_median``: each request's own wall
    time minus its injected latency, median)."""
    advisor = _advisor(spec, timeout_s)
    prompts = [render_fast_prompt(descs[i % len(descs)], memories=_MEMORIES) for i in range(n)]
    for k in range(min(warmup, n)):  # connection, template and schema set-up: once per process, not per request
        advisor.advise(render_fast_prompt(descs[-1 - k], memories=_MEMORIES), variant="fast")
    replies: list[Any] = []
    seconds: dict[int, float] = {}

    def work(i: int) -> Any:
        start = time.perf_counter()
        advice = advisor.advise(render_fast_prompt(descs[i % len(descs)], memories=_MEMORIES), variant="fast")
        seconds[i] = time.perf_counter() - start
        return advice

    cpu0, t0 = time.process_time(), time.perf_counter()
    stats = run_ordered(range(n), work, lambda i, advice: replies.append(advice),
                        config=RunnerConfig(concurrency=concurrency), advisor=advisor,
                        is_fallback=lambda advice: advice.fallback)
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    req = stats.requests
    out: dict[str, Any] = {
        "scenarios": n, "seconds": round(wall, 3), "scenarios_per_s": round(n / wall, 3),
        "client_cpu_ms_per_request": round(1000 * cpu / max(req.requests if req else n, 1), 3),
        "request_p50_s": None if req is None else req.latency_p50_s,
        "request_p95_s": None if req is None else req.latency_p95_s,
        "fallbacks": stats.fallbacks,
        "completion_tokens_per_s": None if req is None else req.completion_tokens_per_s,
    }
    if latency_s is not None:
        each = [latency_for(request_keys({"messages": p})[0], latency_s, jitter) for p in prompts]
        injected = sum(each)
        out["injected_latency_mean_s"] = round(injected / n, 4)
        out["client_overhead_ms_per_request"] = round(1000 * (concurrency * wall - injected) / n, 3)
        out["client_overhead_ms_median"] = round(1000 * float(np.median([seconds[i] - each[i] for i in range(n)])), 3)
    return out


def _ratios(levels: dict[str, dict[str, Any]]) -> dict[str, float]:
    base = levels.get("1", {}).get("scenarios_per_s")
    return {f"{c}_over_1": round(v["scenarios_per_s"] / base, 2) for c, v in levels.items() if base}


def _bank(spec: str, work_dir: Path, n: int) -> tuple[Path, RunStats | None]:
    """A memory bank of ``n`` scenarios collected from ``spec`` (16 in flight) for letspi-fast."""
    path = work_dir / "bank.sqlite"
    options = DEFAULT_OPTIONS.replace(llm=spec, fast_llm=spec, llm_cache=False)
    phase, _ = Builder(cache=None).memory_phase(Resolver(options).memory_phase())
    with MemoryBank.open(path) as bank:
        stats = collect(phase, bench_batch(n, seed=99), bank, runner=RunnerConfig(concurrency=16))
    return path, stats.run


def pipeline_level(spec: str, bank: Path, work_dir: Path, concurrency: int, n: int, seed: int = 1) -> dict[str, Any]:
    """``n`` scenarios of the whole letspi-fast planner through ``evaluate`` (module docstring)."""
    options = DEFAULT_OPTIONS.replace(llm=spec, fast_llm=spec, llm_cache=False, memory=bank)
    planners = build_planners(["letspi-fast"], options, builder=Builder(cache=None))
    runs: dict[str, RunStats] = {}
    batch = bench_batch(n, seed=seed)
    cpu0, t0 = time.process_time(), time.perf_counter()
    evaluate(planners, batch, work_dir / f"eval-{concurrency}-{n}-{seed}", EvaluationSettings(
        concurrency=concurrency, on_run=lambda name, st: runs.__setitem__(name, st)))
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    run = runs["letspi-fast"]
    return {"scenarios": n, "seconds": round(wall, 3), "scenarios_per_s": round(n / wall, 3),
            "client_cpu_ms_per_scenario": round(1000 * cpu / n, 2),
            "physics_cpu_ms_per_scenario": _round(run.physics_cpu_ms_per_scenario),
            "scenario_p50_s": run.scenario_p50_s,
            "scenario_p95_s": run.scenario_p95_s, "fallbacks": run.fallbacks}


def _round(x: float | None, digits: int = 3) -> float | None:
    return None if x is None else round(x, digits)


def _wait_ready(url: str, seconds: float, proc: subprocess.Popen[bytes] | None = None) -> None:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:  # died (e.g. SIGILL: llama.cpp built for another CPU)
            raise RuntimeError(f"{url}: the server exited with code {proc.returncode} before answering"
                               + (" (illegal instruction: llama.cpp was built for another CPU; rebuild it)"
                                  if proc.returncode in (-4, 132) else ""))
        try:
            if httpx.get(f"{url}/models", timeout=2.0).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.5)
    raise RuntimeError(f"{url}: the server did not answer within {seconds:.0f} s")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def real_server_available() -> str | None:
    """None if llama-cpp-python's server and the SmolLM2 model are installed, else why not."""
    try:
        import llama_cpp.server.app  # noqa: F401
    except ImportError as exc:
        return f"llama-cpp-python's server extra is missing ({exc}); pip install 'llama-cpp-python[server]'"
    try:
        locate_model("smollm2-135m")
    except Exception as exc:  # the model package is missing
        return str(exc)
    return None


def start_llama_server(log: Path, *, n_threads: int = 2) -> tuple[_Process, str]:
    """llama-cpp-python's server (``letspi.llm.backends.llamacpp_server``) with the embedded SmolLM2 on a free
    port (verbose log in ``log``)."""
    port = _free_port()
    proc = _Process([sys.executable, "-m", "letspi.llm.backends.llamacpp_server",
                     "--model", str(locate_model("smollm2-135m")), "--model_alias", "smollm2",
                     "--host", "127.0.0.1", "--port", str(port), "--n_ctx", "4096",
                     "--n_threads", str(n_threads), "--n_threads_batch", str(n_threads), "--seed", "0",
                     "--interrupt_requests", "False", "--verbose", "True"], log=log)
    url = f"http://127.0.0.1:{port}/v1"
    try:
        _wait_ready(url, 180.0, proc.proc)
    except RuntimeError:
        proc.close()
        raise
    return proc, url


def prefix_reuse(log_text: str) -> dict[str, Any]:
    """Prompt tokens each request evaluated after the server reused the cached prefix."""
    hits = [(int(a), int(b)) for a, b in _PREFIX_RE.findall(log_text)]
    reused, evaluated = sum(a for a, _ in hits), sum(b for _, b in hits)
    return {"requests_with_prefix_hit": len(hits), "prompt_tokens_reused": reused,
            "prompt_tokens_evaluated": evaluated,
            "reused_fraction": round(reused / (reused + evaluated), 3) if reused + evaluated else None}


def bench_real_server(levels: Sequence[int], per_level: int, descs: Sequence[ScenarioDescription],
                      work_dir: Path) -> dict[str, Any]:
    """The request step against llama-cpp-python's server, and its prefix reuse (module docstring)."""
    why = real_server_available()
    if why is not None:
        return {"skipped": why}
    log = work_dir / "llama_server.log"
    t0 = time.perf_counter()
    server, url = start_llama_server(log)
    out: dict[str, Any] = {"server": "python -m llama_cpp.server (SmolLM2-135M Q4_1, 2 threads, one slot)",
                           "startup_s": round(time.perf_counter() - t0, 1)}
    try:
        spec = f"openai:smollm2@{url}"
        # the physics prompt twice for one scene: initial, then the reflection round (whole first exchange reused)
        advisor = _advisor(spec, timeout_s=600.0)
        first = render_physics_prompt(descs[0])
        a = advisor.advise(first, variant="physics")
        log_before = log.read_text(errors="replace")
        refinement = render_physics_prompt(descs[0], safety_report="t=2.1 s: TTC 1.1 s to the leader ahead",
                                           previous_reply=a.response.text if a.response else "{}")
        b = advisor.advise(refinement, variant="physics")
        step = prefix_reuse(log.read_text(errors="replace")[len(log_before):])
        out["reflection_round"] = {"prompt_tokens": b.prompt_tokens, **step, "first_round_s": round(a.latency_s, 2),
                                   "refinement_round_s": round(b.latency_s, 2), "fallback": a.fallback or b.fallback}
        log_before = log.read_text(errors="replace")
        levels_out: dict[str, dict[str, Any]] = {}
        for c in levels:
            levels_out[str(c)] = request_level(spec, descs[1:], c, max(per_level, c), timeout_s=600.0, warmup=0)
        out["concurrency"] = levels_out
        out["ratios"] = _ratios(levels_out)
        tokens = sum(v["scenarios"] for v in levels_out.values())
        out["fast_prompts"] = {"requests": tokens, **prefix_reuse(log.read_text(errors="replace")[len(log_before):])}
    finally:
        server.close()
    return out


def bench_concurrency(
    levels: Sequence[int] = (1, 4, 16, 64),
    server_latency_ms: float = 200.0,
    *,
    jitter: float = 0.5,
    scenarios_per_level: int = 20,
    pipeline: bool = True,
    projection_scenarios: int = 640,
    real_server: bool = True,
    real_levels: Sequence[int] = (1, 4),
    real_per_level: int = 4,
) -> dict[str, Any]:
    """Run the benchmark (module docstring); a JSON-ready dict. ``scenarios_per_level``: scenarios per
    unit of concurrency (at least 40) for the request step, 8 per unit for the pipeline."""
    load0 = os.getloadavg()
    latency_s = server_latency_ms / 1000.0
    descs = _descriptions(bench_batch(200, seed=7))
    result: dict[str, Any] = {"server_latency_ms": server_latency_ms, "jitter": jitter}
    work_dir = Path(tempfile.mkdtemp(prefix="letspi-bench-"))
    try:
        server, url = start_test_server(server_latency_ms, jitter)
        spec = f"openai:letspi-test@{url}"
        try:
            levels_out = {str(c): request_level(spec, descs, c, max(40, scenarios_per_level * c), latency_s=latency_s,
                                                jitter=jitter) for c in levels}
            result["concurrency"] = levels_out
            result["ratios"] = _ratios(levels_out)
            if pipeline:
                bank, collect_run = _bank(spec, work_dir, 32)
                result["collect"] = {"scenarios": 32, "concurrency": 16,
                                     **(collect_run.as_dict() if collect_run is not None else {})}
                pipe = {str(c): pipeline_level(spec, bank, work_dir, c, max(16, 8 * c)) for c in levels}
                result["pipeline"] = {"concurrency": pipe, "ratios": _ratios(pipe)}
        finally:
            server.close()
        if pipeline and projection_scenarios > 0:
            result["projection"] = _projection(work_dir, work_dir / "bank.sqlite", projection_scenarios)
        result["targets"] = _targets(result)
        if real_server:
            result["real_server"] = bench_real_server(real_levels, real_per_level, descs, work_dir)
    finally:
        shutil.rmtree(work_dir, ignore_errors=True)
    result["machine"] = {"cpus": os.cpu_count(), "load_avg_start": [round(x, 2) for x in load0],
                         "load_avg_end": [round(x, 2) for x in os.getloadavg()]}
    return result


def _projection(work_dir: Path, bank: Path, n: int) -> dict[str, Any]:
    server, url = start_test_server(1000.0, 0.0, slots=64)
    try:
        level = pipeline_level(f"openai:letspi-test@{url}", bank, work_dir, 64, n, seed=5)
    finally:
        server.close()
    rate = level["scenarios_per_s"]
    cpu_bound = 1000.0 / level["client_cpu_ms_per_scenario"] if level["client_cpu_ms_per_scenario"] else None
    return {
        "basis": (f"letspi-fast through evaluate, 64 in flight, against the test server with 64 slots answering "
                  f"in 1 s, {n} scenarios measured; 10,000 / measured rate"),
        "measured": level,
        "projected_10000_s": round(10_000 / rate, 1),
        "projected_10000_min": round(10_000 / rate / 60.0, 2),
        "server_bound_scenarios_per_s": 64.0,
        "client_cpu_bound_scenarios_per_s": None if cpu_bound is None else round(cpu_bound, 1),
    }


def _targets(result: dict[str, Any]) -> dict[str, Any]:
    ratios = result.get("ratios", {})
    one = result.get("concurrency", {}).get("1", {})
    proj = result.get("projection", {})
    got = {"speedup_16": ratios.get("16_over_1"), "speedup_64": ratios.get("64_over_1"),
           "client_overhead_ms": one.get("client_overhead_ms_per_request"),
           "projection_s": proj.get("projected_10000_s"),
           "physics_cpu_ms": proj.get("measured", {}).get("physics_cpu_ms_per_scenario")}
    met = {k: (None if v is None else (v >= TARGETS[k] if k.startswith("speedup") else v <= TARGETS[k]))
           for k, v in got.items()}
    return {"measured": got, "target": TARGETS, "met": met}
