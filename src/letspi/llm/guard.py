"""Run-level state shared by every request of one ``ParamAdvisor`` (thread-safe): a circuit breaker and counters.

``CircuitBreaker`` counts consecutive transport failures over all requests in flight (any answer resets
it); at the budget, or when a caller trips it, every request raises ``RunStoppedError`` before its next
attempt and backoff waits end, so a dead server costs a bounded number of requests, not one fallback per
scenario. ``RequestStats`` counts requests for progress lines and run summaries.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from letspi.llm.types import LLMTransportError, RunStoppedError

DEFAULT_MAX_CONSECUTIVE_FAILURES = 8


def default_failure_budget(concurrency: int) -> int:
    """Consecutive failed requests that stop a run with ``concurrency`` scenarios in flight:
    ``max(8, 2 N)``, so one blip that fails every request in flight once does not stop it."""
    return max(DEFAULT_MAX_CONSECUTIVE_FAILURES, 2 * int(concurrency))


class CircuitBreaker:
    """A run-wide failure budget; the runner resets it at the start of each run."""

    def __init__(self, max_consecutive_failures: int = DEFAULT_MAX_CONSECUTIVE_FAILURES) -> None:
        if max_consecutive_failures < 1:
            raise ValueError("max_consecutive_failures must be >= 1")
        self._lock = threading.Lock()
        self._stopped = threading.Event()
        self.max_consecutive_failures = max_consecutive_failures
        self._consecutive = 0
        self._cause: str | None = None

    def reset(self, max_consecutive_failures: int | None = None) -> None:
        """Start a new run: close the breaker, forget the count (optionally with a new budget)."""
        with self._lock:
            if max_consecutive_failures is not None:
                if max_consecutive_failures < 1:
                    raise ValueError("max_consecutive_failures must be >= 1")
                self.max_consecutive_failures = max_consecutive_failures
            self._consecutive = 0
            self._cause = None
            self._stopped.clear()

    @property
    def tripped(self) -> bool:
        return self._stopped.is_set()

    @property
    def cause(self) -> str | None:
        return self._cause

    @property
    def consecutive_failures(self) -> int:
        return self._consecutive

    def check(self) -> None:
        """Raise ``RunStoppedError`` (naming the first cause) if the breaker has tripped."""
        if self._stopped.is_set():
            raise RunStoppedError(self._cause or "the run was stopped")

    def trip(self, cause: str) -> None:
        """Stop the run; the first cause is kept (later ones are consequences)."""
        with self._lock:
            if not self._stopped.is_set():
                self._cause = cause
                self._stopped.set()

    def record_success(self) -> None:
        """The server answered (valid or not): the failure streak ends."""
        with self._lock:
            self._consecutive = 0

    def record_failure(self, exc: LLMTransportError) -> None:
        """One attempt failed in transport; raises ``RunStoppedError`` if that spends the budget."""
        with self._lock:
            self._consecutive += 1
            spent = self._consecutive >= self.max_consecutive_failures
            n = self._consecutive
        if spent:
            self.trip(f"stopped after {n} consecutive failed requests (last: {exc})")
            self.check()

    def wait(self, seconds: float) -> None:
        """Sleep ``seconds`` (a backoff), waking at once with ``RunStoppedError`` if the run stops."""
        if self._stopped.wait(max(seconds, 0.0)):
            self.check()


@dataclass(frozen=True)
class RequestSnapshot:
    """Counters of one run's requests. ``latency_p50_s`` / ``p95``: requests that really ran the
    model (cache hits and failures excluded); tokens likewise."""

    in_flight: int
    requests: int
    failed: int
    cached: int
    latency_p50_s: float | None
    latency_p95_s: float | None
    prompt_tokens: int
    completion_tokens: int
    seconds: float

    @property
    def tokens_per_s(self) -> float | None:
        """Prompt plus completion tokens of live requests per second of wall time."""
        return (self.prompt_tokens + self.completion_tokens) / self.seconds if self.seconds > 0 else None

    @property
    def completion_tokens_per_s(self) -> float | None:
        return self.completion_tokens / self.seconds if self.seconds > 0 else None


class RequestStats:
    """Thread-safe request counters of one run (see ``RequestSnapshot``)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.reset()

    def reset(self) -> None:
        with self._lock:
            self._t0 = time.perf_counter()
            self._in_flight = self._requests = self._failed = self._cached = 0
            self._prompt_tokens = self._completion_tokens = 0
            self._latencies: list[float] = []

    def begin(self) -> None:
        with self._lock:
            self._in_flight += 1

    def end(self, *, ok: bool, cached: bool = False, latency_s: float | None = None, prompt_tokens: int = 0,
            completion_tokens: int = 0) -> None:
        """One request finished: ``ok`` False for a transport failure; a live reply passes its latency."""
        with self._lock:
            self._in_flight -= 1
            self._requests += 1
            if not ok:
                self._failed += 1
            elif cached:
                self._cached += 1
            elif latency_s is not None:
                self._latencies.append(latency_s)
                self._prompt_tokens += prompt_tokens
                self._completion_tokens += completion_tokens

    @property
    def in_flight(self) -> int:
        return self._in_flight

    def snapshot(self) -> RequestSnapshot:
        with self._lock:
            lat = np.asarray(self._latencies, dtype=np.float64)
            return RequestSnapshot(
                in_flight=self._in_flight, requests=self._requests, failed=self._failed, cached=self._cached,
                latency_p50_s=float(np.percentile(lat, 50)) if len(lat) else None,
                latency_p95_s=float(np.percentile(lat, 95)) if len(lat) else None,
                prompt_tokens=self._prompt_tokens, completion_tokens=self._completion_tokens,
                seconds=time.perf_counter() - self._t0,
            )
