"""Run one task per scenario, N at a time (threads), and store the results through one writer in scenario order, so
neither the finishing order nor an interrupted run changes what is stored (``concurrency`` is in no key). A task
raising ``RequestFailedError`` is a failed scenario (nothing written; the run ends with ``ScenariosFailedError``);
any other exception stops the run: queued tasks cancelled, the advisor's breaker tripped, the in-order prefix
written, the first error raised."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

import numpy as np

from letspi.llm.client import ParamAdvisor
from letspi.llm.guard import RequestSnapshot, default_failure_budget
from letspi.llm.types import LLMTransportError, RequestFailedError

R = TypeVar("R")
T = TypeVar("T")

#: How often (s) the progress callback hears from a run even when nothing finishes.
PROGRESS_INTERVAL_S = 0.5


@dataclass(frozen=True)
class RunnerConfig:
    """How a run executes (never what it answers). concurrency: scenarios in flight (1: in the calling thread).
    max_consecutive_failures: failed requests in a row that stop the run (None: ``default_failure_budget``, max(8, 2
    N)). reorder_window: finished scenarios that may wait for an earlier one before submission pauses."""

    concurrency: int = 1
    max_consecutive_failures: int | None = None
    reorder_window: int = 1024

    def __post_init__(self) -> None:
        if self.concurrency < 1:
            raise ValueError(f"--concurrency must be >= 1, got {self.concurrency}")
        if self.max_consecutive_failures is not None and self.max_consecutive_failures < 1:
            raise ValueError("max_consecutive_failures must be >= 1")
        if self.reorder_window < 0:
            raise ValueError("reorder_window must be >= 0")

    @property
    def failure_budget(self) -> int:
        return self.max_consecutive_failures or default_failure_budget(self.concurrency)


@dataclass(frozen=True)
class RunStatus:
    """A progress snapshot: ``done`` (finished in this run, written or failed), ``requests_in_flight`` (None without
    an advisor) and ``running`` (tasks between submission and completion)."""

    done: int
    total: int
    written: int
    failed: int
    fallbacks: int
    running: int
    requests_in_flight: int | None
    elapsed_s: float

    @property
    def scenarios_per_s(self) -> float:
        return self.done / self.elapsed_s if self.elapsed_s > 0 else 0.0

    @property
    def eta_s(self) -> float | None:
        rate = self.scenarios_per_s
        return (self.total - self.done) / rate if rate > 0 else None


@dataclass(frozen=True)
class RunStats:
    """One run's counts, wall time, task times of written scenarios and the advisor's counters (None without)."""

    total: int
    written: int
    failed: int
    fallbacks: int
    seconds: float
    concurrency: int
    scenario_s: tuple[float, ...] = ()
    requests: RequestSnapshot | None = None
    physics_cpu_s: float | None = None  # CPU time of the batched physics and metrics, when the run had them

    @property
    def scenarios_per_s(self) -> float | None:
        done = self.written + self.failed
        return done / self.seconds if self.seconds > 0 and done else None

    def _pct(self, q: float) -> float | None:
        return float(np.percentile(self.scenario_s, q)) if self.scenario_s else None

    @property
    def scenario_p50_s(self) -> float | None:
        return self._pct(50)

    @property
    def scenario_p95_s(self) -> float | None:
        return self._pct(95)

    def as_dict(self) -> dict[str, Any]:
        req = self.requests
        return {
            "scenarios": self.total, "written": self.written, "failed": self.failed, "fallbacks": self.fallbacks,
            "seconds": round(self.seconds, 3), "concurrency": self.concurrency,
            "scenarios_per_s": _r(self.scenarios_per_s), "scenario_p50_s": _r(self.scenario_p50_s),
            "scenario_p95_s": _r(self.scenario_p95_s),
            "requests": None if req is None else req.requests, "requests_cached": None if req is None else req.cached,
            "requests_failed": None if req is None else req.failed,
            "request_p50_s": None if req is None else _r(req.latency_p50_s),
            "request_p95_s": None if req is None else _r(req.latency_p95_s),
            "tokens_per_s": None if req is None else _r(req.tokens_per_s),
            "completion_tokens_per_s": None if req is None else _r(req.completion_tokens_per_s),
            "physics_cpu_ms_per_scenario": _r(self.physics_cpu_ms_per_scenario),
        }

    @property
    def physics_cpu_ms_per_scenario(self) -> float | None:
        """CPU time of the batched physics and metrics per written scenario [ms] (None if not pooled)."""
        if self.physics_cpu_s is None or not self.written:
            return None
        return 1000.0 * self.physics_cpu_s / self.written

    def summary_line(self) -> str:
        """One line for the end of a run: throughput, latency percentiles, tokens/s, fallbacks."""
        if self.total == 0:
            return "nothing to do (every scenario already stored)"
        parts = [f"{self.written + self.failed} scenarios in {self.seconds:.1f} s "
                 f"({_fmt(self.scenarios_per_s)} scenarios/s, concurrency {self.concurrency})"]
        if self.scenario_s:
            parts.append(f"scenario p50 {_fmt(self.scenario_p50_s)} s / p95 {_fmt(self.scenario_p95_s)} s")
        req = self.requests
        if req is not None and req.requests:
            live = req.requests - req.cached - req.failed
            lat = (f", p50 {_fmt(req.latency_p50_s)} s / p95 {_fmt(req.latency_p95_s)} s"
                   if req.latency_p50_s is not None else "")
            parts.append(f"{req.requests} requests ({req.cached} cached, {req.failed} failed{lat}); "
                         f"{_fmt(req.tokens_per_s)} tokens/s over {live} live requests")
        if self.physics_cpu_ms_per_scenario is not None:
            parts.append(f"physics {_fmt(self.physics_cpu_ms_per_scenario)} ms CPU per scenario")
        parts.append(f"{self.fallbacks} fallbacks, {self.failed} failed (not stored)")
        return "; ".join(parts)


def _r(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), 4)


def _fmt(x: float | None) -> str:
    if x is None:
        return "n/a"
    return f"{x:.3g}" if abs(x) < 100 else f"{x:,.0f}"


class ScenariosFailedError(LLMTransportError):
    """Some scenarios got no answer (``RequestFailedError``) and were not stored (a rerun retries exactly those);
    ``stats``: the run's ``RunStats``."""

    def __init__(self, message: str, *, stats: RunStats) -> None:
        super().__init__(message)
        self.stats = stats


class _InlineExecutor:
    """``concurrency = 1``: run each task at submission, in the calling thread."""

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future[Any]:
        fut: Future[Any] = Future()
        try:
            fut.set_result(fn(*args))
        except Exception as exc:  # KeyboardInterrupt and SystemExit propagate at once
            fut.set_exception(exc)
        return fut

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        pass


@dataclass
class _Done(Generic[R]):
    value: R | None = None
    seconds: float = 0.0
    failed: BaseException | None = None  # RequestFailedError: skip it
    stopped: bool = False  # another error: nothing at or after this position is written


@dataclass
class _Counts:
    written: int = 0
    failed: int = 0
    fallbacks: int = 0
    seconds: list[float] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)


def run_ordered(
    indices: Sequence[int],
    work: Callable[[int], R],
    write: Callable[[int, R], None],
    *,
    config: RunnerConfig | None = None,
    advisor: ParamAdvisor | None = None,
    is_fallback: Callable[[R], bool] | None = None,
    progress: Callable[[RunStatus], None] | None = None,
) -> RunStats:
    """``work(i)`` for every i of ``indices`` (``config.concurrency`` at a time); ``write(i, result)`` in
    the order of ``indices``, in the calling thread. ``advisor``: the tasks' LLM advisor (its breaker reset
    and tripped by the run). Raises the first stopping error, or ``ScenariosFailedError``."""
    config = config or RunnerConfig()
    n = len(indices)
    if advisor is not None:
        advisor.breaker.reset(config.failure_budget)
        advisor.stats.reset()
    t0 = time.perf_counter()
    counts = _Counts()
    buffer: dict[int, _Done[R]] = {}
    pending: dict[Future[tuple[R, float]], int] = {}
    next_submit = next_write = 0
    first_error: BaseException | None = None

    def timed(i: int) -> tuple[R, float]:
        start = time.perf_counter()
        value = work(i)
        return value, time.perf_counter() - start

    def report() -> None:
        if progress is not None:
            progress(RunStatus(done=counts.written + counts.failed, total=n, written=counts.written,
                               failed=counts.failed, fallbacks=counts.fallbacks, running=len(pending),
                               requests_in_flight=None if advisor is None else advisor.stats.in_flight,
                               elapsed_s=time.perf_counter() - t0))

    def stop(exc: BaseException) -> None:
        nonlocal first_error
        if first_error is None:
            first_error = exc
            if advisor is not None:
                advisor.breaker.trip(f"the run stopped: {exc}")

    executor: ThreadPoolExecutor | _InlineExecutor = (
        _InlineExecutor() if config.concurrency == 1 else
        ThreadPoolExecutor(max_workers=config.concurrency, thread_name_prefix="letspi-scenario"))
    interrupted = False

    def submit() -> None:
        nonlocal next_submit
        while (first_error is None and next_submit < n and len(pending) < config.concurrency
               and next_submit - next_write < config.concurrency + config.reorder_window):
            pending[executor.submit(timed, indices[next_submit])] = next_submit
            next_submit += 1

    try:
        while next_write < n:
            submit()
            if pending:
                finished, _ = wait(list(pending), timeout=PROGRESS_INTERVAL_S, return_when=FIRST_COMPLETED)
                for fut in finished:
                    pos = pending.pop(fut)
                    try:
                        value, seconds = fut.result()
                        buffer[pos] = _Done(value, seconds)
                    except RequestFailedError as exc:
                        buffer[pos] = _Done(failed=exc)
                    except Exception as exc:
                        stop(exc)
                        buffer[pos] = _Done(stopped=True)
                if config.concurrency > 1:
                    submit()  # refill the freed slots before writing: a write may take a while (a part's physics)
            while next_write in buffer and not buffer[next_write].stopped:
                done = buffer.pop(next_write)
                if done.failed is not None:
                    counts.failed += 1
                    counts.failures.append(str(done.failed))
                else:
                    result: R = done.value  # type: ignore[assignment]
                    write(indices[next_write], result)
                    counts.written += 1
                    counts.seconds.append(done.seconds)
                    if is_fallback is not None and is_fallback(result):
                        counts.fallbacks += 1
                next_write += 1
            report()
            if first_error is not None and not pending:
                break
    except BaseException as exc:  # a write failed, or Ctrl-C: stop the tasks in flight
        interrupted = isinstance(exc, KeyboardInterrupt)
        stop(exc)
        raise
    finally:
        for fut in pending:
            fut.cancel()
        executor.shutdown(wait=not interrupted, cancel_futures=True)
    if first_error is not None:
        raise first_error
    stats = RunStats(total=n, written=counts.written, failed=counts.failed, fallbacks=counts.fallbacks,
                     seconds=time.perf_counter() - t0, concurrency=config.concurrency,
                     scenario_s=tuple(counts.seconds),
                     requests=None if advisor is None else advisor.stats.snapshot())
    if counts.failed:
        raise ScenariosFailedError(
            f"{counts.failed} of {n} scenarios got no answer from the LLM server and were not stored "
            f"(first: {counts.failures[0]}); rerun the same command to retry them", stats=stats)
    return stats


class BlockCache(Generic[T]):
    """``compute(slice)`` once per fixed block of positions, by the first thread to ask (the others wait), so a value
    depends neither on the concurrency nor on what a run already stored."""

    def __init__(self, size: int, n: int, compute: Callable[[slice], T]) -> None:
        if size < 1:
            raise ValueError(f"block size must be >= 1, got {size}")
        self.size, self.n = size, n
        self._compute = compute
        self._values: dict[int, tuple[T, float]] = {}
        self._locks: dict[int, threading.Lock] = {}
        self._guard = threading.Lock()
        self.cpu_s = 0.0  # CPU time spent computing blocks (their threads' CPU time) [s]

    def block_of(self, position: int) -> tuple[int, int]:
        """(block index, offset of ``position`` in it)."""
        return divmod(int(position), self.size)

    def block_len(self, block: int) -> int:
        return min(self.size, self.n - block * self.size)

    def get(self, position: int) -> tuple[T, int, float]:
        """(the value of ``position``'s block, the offset in it, its computing time per position [s])."""
        block, offset = self.block_of(position)
        with self._guard:
            lock = self._locks.setdefault(block, threading.Lock())
        with lock:
            if block not in self._values:
                start = self.size * block
                t0, c0 = time.perf_counter(), time.thread_time()
                value = self._compute(slice(start, start + self.block_len(block)))
                self._values[block] = (value, (time.perf_counter() - t0) / self.block_len(block))
                with self._guard:
                    self.cpu_s += time.thread_time() - c0
            value, seconds = self._values[block]
        return value, offset, seconds

    def discard_below(self, position: int) -> None:
        """Forget the blocks that end at or before ``position`` (positions below it are done)."""
        with self._guard:
            for block in [b for b in self._values if self.size * (b + 1) <= position]:
                del self._values[block]
                self._locks.pop(block, None)
