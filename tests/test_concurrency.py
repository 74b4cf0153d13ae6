"""N scenarios in flight against a real local HTTP server (``benchmarks.llm_server``): one writer in
scenario order, Retry-After per request, a circuit breaker for a dead server, exact resume."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pandas as pd
import pytest
from concurrency_support import bank_rows, collect_into, options, scenarios, stored_results
from typer.testing import CliRunner

from benchmarks.llm_server import ChatRequest, Fault, LlmTestServer
from letspi.assembly.build import Builder
from letspi.assembly.planners import build_planners
from letspi.assembly.resolve import Resolver
from letspi.cli.app import app
from letspi.evaluation.harness import EvaluationSettings, evaluate
from letspi.evaluation.results import load_planner_results
from letspi.execution.ordered import RunnerConfig, ScenariosFailedError, run_ordered
from letspi.llm.client import RetryPolicy
from letspi.llm.guard import CircuitBreaker
from letspi.llm.types import BackendUnavailableError, LLMTransportError, RequestFailedError, RunStoppedError
from letspi.method.memory import MemoryBank
from letspi.scenario.store import save_scenarios

SRC = str(Path(__file__).resolve().parents[1] / "src")


# --- the runner on its own ---------------------------------------------------------------------


def test_writes_follow_scenario_order_whatever_order_tasks_finish_in() -> None:
    finished: list[int] = []
    written: list[int] = []

    def work(i: int) -> int:
        time.sleep(0.02 * (8 - i))  # the first scenarios take longest
        finished.append(i)
        return i * i

    stats = run_ordered(list(range(8)), work, lambda i, r: written.append(r), config=RunnerConfig(concurrency=8))
    assert finished != sorted(finished)  # they did finish out of order
    assert written == [i * i for i in range(8)] and stats.written == 8 and stats.failed == 0


def test_a_failed_scenario_is_skipped_and_the_run_ends_with_one_error() -> None:
    written: list[int] = []

    def work(i: int) -> int:
        if i == 2:
            raise RequestFailedError("HTTP 500 three times")
        return i

    with pytest.raises(ScenariosFailedError, match=r"1 of 5 scenarios .* not stored .*HTTP 500.*rerun"):
        run_ordered(range(5), work, lambda i, r: written.append(r), config=RunnerConfig(concurrency=3))
    assert written == [0, 1, 3, 4]


def test_any_other_error_stops_the_run_after_writing_the_prefix_before_it() -> None:
    written: list[int] = []

    def work(i: int) -> int:
        if i == 3:
            raise ValueError("broken scenario 3")
        time.sleep(0.01)
        return i

    with pytest.raises(ValueError, match="broken scenario 3"):
        run_ordered(range(40), work, lambda i, r: written.append(r), config=RunnerConfig(concurrency=4))
    assert written == [0, 1, 2]  # nothing at or after the failed position


def test_breaker_trips_after_consecutive_failures_only_and_wakes_sleepers() -> None:
    breaker = CircuitBreaker(max_consecutive_failures=3)
    err = LLMTransportError("HTTP 500")
    breaker.record_failure(err)
    breaker.record_failure(err)
    breaker.record_success()  # the streak ends
    breaker.record_failure(err)
    breaker.record_failure(err)
    assert not breaker.tripped
    with pytest.raises(RunStoppedError, match="stopped after 3 consecutive failed requests.*HTTP 500"):
        breaker.record_failure(err)
    breaker.reset()
    t0 = time.monotonic()
    import threading

    threading.Timer(0.1, breaker.trip, args=("server gone",)).start()
    with pytest.raises(RunStoppedError, match="server gone"):
        breaker.wait(5.0)  # a backoff wait ends when the run stops
    assert time.monotonic() - t0 < 2.0


# --- against the local server ------------------------------------------------------------------


def test_shuffled_completion_order_gives_the_same_memory_bank(tmp_path: Path) -> None:
    """N = 1 and N = 8 store the same rows, ids included, although the server's latency jitter makes
    the N = 8 run's replies come back in another order than their requests went out."""
    batch = scenarios(20)
    with LlmTestServer(latency_s=0.04, jitter=0.95) as srv:
        for n in (1, 8):
            stats = collect_into(tmp_path / f"bank{n}.sqlite", srv.spec(), batch, concurrency=n)
            assert stats.stored == 20 and stats.run is not None and stats.run.concurrency == n
        sent = [r.key for r in srv.arrivals[-30:]]
        done = [k for _, k, _ in srv.completed[-30:]]
    assert sent != done  # the N = 8 run's replies arrived out of order
    rows = bank_rows(tmp_path / "bank1.sqlite")
    assert rows == bank_rows(tmp_path / "bank8.sqlite")
    assert [r["id"] for r in rows] == list(range(1, 21)) and [r["scenario_id"] for r in rows] == list(batch.scenario_id)
    assert any(r["n_iterations"] > 1 for r in rows)  # reflection rounds ran


def test_shuffled_completion_order_gives_the_same_evaluation_rows(tmp_path: Path) -> None:
    batch = scenarios(16, seed=1)
    with LlmTestServer(latency_s=0.04, jitter=0.95) as srv:
        collect_into(tmp_path / "bank.sqlite", srv.spec(), batch, concurrency=8)
        for n in (1, 8):
            planners = build_planners(["letspi-fast", "llm"], options(srv.spec(), tmp_path / "bank.sqlite"))
            evaluate(planners, batch, tmp_path / f"eval{n}", EvaluationSettings(concurrency=n))
    for name in ("letspi-fast", "llm"):
        one, eight = stored_results(tmp_path / "eval1", name), stored_results(tmp_path / "eval8", name)
        assert len(one) == 16
        pd.testing.assert_frame_equal(one, eight)
    run1 = (tmp_path / "eval1" / "run.json").read_text()
    assert run1 == (tmp_path / "eval8" / "run.json").read_text()  # concurrency is in no key


def test_retry_after_delays_that_request_and_nothing_else(tmp_path: Path) -> None:
    batch = scenarios(16)
    target: list[str] = []

    def fault(req: ChatRequest) -> Fault | None:
        if not target:
            target.append(req.scenario_key)  # the first scenario to arrive is rate limited once
            return Fault(429, "slow down", {"Retry-After": "1"})
        return None

    with LlmTestServer(latency_s=0.05, fault=fault) as srv:
        planners = build_planners(["llm"], options(srv.spec(), max_iterations=0))
        evaluate(planners, batch, tmp_path / "eval", EvaluationSettings(concurrency=4))
        mine = [r.arrived for r in srv.arrivals if r.scenario_key == target[0]]
        others = [r.arrived for r in srv.arrivals if r.scenario_key != target[0]]
    assert len(mine) == 2 and mine[1] - mine[0] >= 1.0  # 429, then the retry after >= 1 s
    during = [t for t in others if mine[0] < t < mine[1]]
    assert len(during) >= 8  # the other workers kept sending meanwhile
    rows = load_planner_results(tmp_path / "eval", "llm")
    slow = rows["inference_s"][rows["info_llm_calls"] == 2]
    fast = rows["inference_s"][rows["info_llm_calls"] == 1]
    assert len(slow) == 1 and float(slow.iloc[0]) >= 1.0
    assert len(fast) == 15 and float(fast.max()) < 0.8


def test_a_dead_server_stops_the_run_after_a_bounded_number_of_failures_and_the_rerun_completes(
    tmp_path: Path,
) -> None:
    batch = scenarios(30)
    quick = RetryPolicy(max_attempts=3, backoff_s=0.05, max_backoff_s=0.1, timeout_s=5.0)
    healthy: set[str] = set()

    def dies_after_ten_scenarios(req: ChatRequest) -> Fault | None:
        if req.scenario_key in healthy or len(healthy) < 10:
            healthy.add(req.scenario_key)
            return None
        return Fault(500, "llama runner process has terminated")

    bank = tmp_path / "bank.sqlite"
    with LlmTestServer(latency_s=0.01) as srv:
        collect_into(tmp_path / "reference.sqlite", srv.spec(), batch, concurrency=4)  # never interrupted
        srv.fault = dies_after_ten_scenarios
        n0 = len(srv.arrivals)
        with pytest.raises(RunStoppedError) as stop:
            collect_into(bank, srv.spec(), batch, concurrency=4, retry=quick)
        message = str(stop.value)
        assert "stopped after 8 consecutive failed requests" in message and "HTTP 500" in message
        assert srv.base_url in message and "\n" not in message
        statuses = [status for _, _, status in srv.completed[n0:]]
        after_last_success = statuses[len(statuses) - statuses[::-1].index(200):]
        # once the server only fails: the budget, plus at most one request per worker in flight; the server's
        # completion order may put up to one success per other worker after failures the client saw later
        assert 8 - 3 <= len(after_last_success) <= 8 + 4 and set(after_last_success) == {500}
        assert statuses.count(500) >= 8
        with MemoryBank.open(bank, readonly=True) as b:
            stored = b.count(validated_only=False)
        assert 1 <= stored <= 10
        srv.fault = None  # the server is back
        again = collect_into(bank, srv.spec(), batch, concurrency=4, retry=quick)
    assert again.skipped == stored and again.stored == 30 - stored
    assert bank_rows(bank) == bank_rows(tmp_path / "reference.sqlite")


def test_cli_a_dead_server_is_one_message_and_the_rerun_completes(tmp_path: Path) -> None:
    path = save_scenarios(scenarios(6), tmp_path / "s.arrow")
    args = ["collect", "--scenarios", str(path), "--memory", str(tmp_path / "m.sqlite"), "--goals", "kinematic",
            "--no-cache", "--concurrency", "3"]
    with LlmTestServer(latency_s=0.01, fault=lambda r: Fault(503, "loading model")) as srv:
        result = CliRunner().invoke(app, [*args, "--llm", srv.spec()])
        assert result.exit_code == 2, result.output
        errors = [line for line in result.output.splitlines() if line.startswith("error:")]
        text = " ".join(result.output.split())  # rich wraps long lines at the terminal width
        assert len(errors) == 1 and "stopped after 8 consecutive failed requests" in text and "HTTP 503" in text
        assert "rerun the same command to resume" in text
        srv.fault = None
        result = CliRunner().invoke(app, [*args, "--llm", srv.spec()])
    assert result.exit_code == 0, result.output
    assert "scenarios/s" in result.output and "tokens/s" in result.output and "p95" in result.output
    with MemoryBank.open(tmp_path / "m.sqlite", readonly=True) as bank:
        assert bank.count(validated_only=False) == 6


def test_an_unreachable_server_stops_at_once(tmp_path: Path) -> None:
    with LlmTestServer() as srv:
        spec = srv.spec()  # a port that then closes
    with pytest.raises(BackendUnavailableError, match="cannot reach"):
        collect_into(tmp_path / "m.sqlite", spec, scenarios(20), concurrency=8,
                     retry=RetryPolicy(max_attempts=2, backoff_s=0.05, timeout_s=2.0))
    with MemoryBank.open(tmp_path / "m.sqlite", readonly=True) as bank:
        assert bank.count(validated_only=False) == 0


_KILLABLE_RUN = """
import sys
from pathlib import Path
import letspi.evaluation.concurrent
from letspi.cli.app import app
letspi.evaluation.concurrent.PART_SCENARIOS = 5  # several parts, so the kill lands between two of them
out, spec, scenarios, what = Path(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4]
common = ["--scenarios", scenarios, "--llm", spec, "--goals", "kinematic", "--no-cache", "--concurrency", "8"]
if what == "collect":
    app(["collect", "--memory", str(out / "bank.sqlite"), *common])
else:
    app(["evaluate", "--out", str(out / "eval"), "--planner", "llm", "--max-iterations", "1", *common])
"""


def _run(out: Path, spec: str, scenario_file: Path, what: str, kill_when: Callable[[], bool] | None = None) -> None:
    """Run the CLI in a child process; with ``kill_when``, SIGKILL it as soon as that holds."""
    env = {**os.environ, "PYTHONPATH": SRC}
    proc = subprocess.Popen([sys.executable, "-c", _KILLABLE_RUN, str(out), spec, str(scenario_file), what],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    if kill_when is None:
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err.decode()[-2000:]
        return
    deadline = time.monotonic() + 120
    while proc.poll() is None and time.monotonic() < deadline and not kill_when():
        time.sleep(0.01)
    assert proc.poll() is None, "the run ended before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()


def _bank_count(path: Path) -> int:
    try:
        with MemoryBank.open(path, readonly=True) as bank:
            return bank.count(validated_only=False)
    except Exception:  # not created yet
        return 0


@pytest.mark.slow  # over ~10 s on a loaded 2-core machine (notes/reliability.md)
def test_kill_9_mid_collection_then_rerun_gives_the_uninterrupted_bank(tmp_path: Path) -> None:
    """8 scenarios in flight, SIGKILL mid-run, rerun: the same rows (ids included) as a run that was
    never interrupted; no duplicate, none missing."""
    batch = scenarios(40, seed=3)
    scenario_file = save_scenarios(batch, tmp_path / "s.arrow")
    bank = tmp_path / "killed" / "bank.sqlite"
    with LlmTestServer(latency_s=0.03, jitter=0.9) as srv:
        collect_into(tmp_path / "reference.sqlite", srv.spec(), batch, concurrency=8)
        _run(tmp_path / "killed", srv.spec(), scenario_file, "collect", kill_when=lambda: _bank_count(bank) >= 8)
        partial = _bank_count(bank)
        _run(tmp_path / "killed", srv.spec(), scenario_file, "collect")
    assert 8 <= partial < 40
    rows = bank_rows(bank)
    assert rows == bank_rows(tmp_path / "reference.sqlite") and len(rows) == 40


@pytest.mark.slow  # over ~10 s on a loaded 2-core machine (notes/reliability.md)
def test_kill_9_mid_evaluation_then_rerun_gives_the_uninterrupted_results(tmp_path: Path) -> None:
    batch = scenarios(30, seed=4)
    scenario_file = save_scenarios(batch, tmp_path / "s.arrow")
    parts = tmp_path / "killed" / "eval" / "per_scenario" / "llm"
    with LlmTestServer(latency_s=0.03, jitter=0.9) as srv:
        evaluate(build_planners(["llm"], options(srv.spec(), max_iterations=1)), batch, tmp_path / "reference",
             EvaluationSettings(concurrency=8))
        _run(tmp_path / "killed", srv.spec(), scenario_file, "evaluate",
             kill_when=lambda: len(list(parts.glob("part-*.parquet"))) >= 2)
        stored = sum(len(pd.read_parquet(p, columns=["row"])) for p in parts.glob("part-*.parquet"))
        _run(tmp_path / "killed", srv.spec(), scenario_file, "evaluate")
    assert 10 <= stored < 30
    raw = pd.concat([pd.read_parquet(p, columns=["scenario_digest"]) for p in parts.glob("part-*.parquet")])
    assert len(raw) == 30 and raw["scenario_digest"].is_unique  # no duplicate, no missing row
    pd.testing.assert_frame_equal(stored_results(tmp_path / "killed" / "eval", "llm"),
                                  stored_results(tmp_path / "reference", "llm"))


def test_request_timeout_reaches_the_advisor_and_changes_no_key() -> None:
    default = Resolver(options("scripted:default")).memory_phase()
    short = Resolver(options("scripted:default", llm_timeout_s=7.0)).memory_phase()
    assert short.key() == default.key() and short.llm.timeout_s == 7.0
    phase, _ = Builder(cache=None).memory_phase(short)
    assert phase.advisor.retry.timeout_s == 7.0
