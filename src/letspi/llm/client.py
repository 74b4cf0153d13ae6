"""``ParamAdvisor``: ask a backend for parameters, with cache, validation, retries and fallback.

``advise`` makes up to ``RetryPolicy.max_attempts`` calls, each through the response cache:
* transport error or timeout: resend the same messages after ``RetryPolicy.wait_s`` (this request only);
* invalid reply: resend at once with that reply echoed and a corrective message (a different cache key);
* ``RequestRejectedError`` (e.g. a prompt over the context): stop, the same request would be refused again.
Without a valid reply: ``DEFAULT_REPLY`` with ``fallback=True`` if the model answered every attempt, else
``RequestFailedError`` (the scenario is not stored; a rerun retries it). ``BackendUnavailableError`` when
every attempt found the server unreachable, ``ServerBusyError`` for a ``Retry-After`` over the limit,
``RunStoppedError`` once the run-wide breaker (``letspi.llm.guard``) trips. Thread-safe.
"""

from __future__ import annotations

import random
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Final, Literal, TypeVar

from letspi.llm.cache import CachedEntry, ResponseCache, backend_identity, cache_key
from letspi.llm.choice import CHOICE_KEY, choice_json_schema, parse_choice
from letspi.llm.guard import CircuitBreaker, RequestStats
from letspi.llm.parse import parse_reply, try_parse_json
from letspi.llm.schema import DEFAULT_REPLY, WIRE_KEYS, PlannerReply, Variant, reply_json_schema
from letspi.llm.spec import installed_origin, make_backend
from letspi.llm.types import (
    BackendUnavailableError,
    DecodingSettings,
    LLMBackend,
    LLMResponse,
    LLMTimeoutError,
    LLMTransportError,
    Message,
    ReplyParseError,
    RequestFailedError,
    RequestRejectedError,
    ServerBusyError,
    message,
)

#: ``Attempt.error_kind`` values of transport failures (the request may succeed if retried later).
TRANSPORT_KINDS = frozenset({"transport", "timeout", "unavailable", "busy"})

#: Bad replies are cut to this many characters when echoed back in a corrective message.
_ECHO_CHARS = 600


@dataclass(frozen=True)
class RetryPolicy:
    """How hard to try: ``max_attempts`` counts all calls (1 = no retry); the wait after a transport failure is
    ``wait_s``. A ``Retry-After`` above ``max_retry_after_s`` raises ``ServerBusyError``."""

    max_attempts: int = 3
    backoff_s: float = 0.5
    backoff_factor: float = 2.0
    max_backoff_s: float = 8.0
    jitter: float = 0.5
    max_retry_after_s: float = 120.0
    timeout_s: float = 120.0

    def __post_init__(self) -> None:
        if self.max_attempts < 1:
            raise ValueError("max_attempts must be >= 1")
        if self.timeout_s <= 0:
            raise ValueError("timeout_s must be > 0")
        if not 0.0 <= self.jitter <= 1.0:
            raise ValueError("jitter must be in [0, 1]")
        if self.backoff_s < 0 or self.max_backoff_s < 0 or self.max_retry_after_s < 0:
            raise ValueError("backoff_s, max_backoff_s and max_retry_after_s must be >= 0")

    def delay(self, failures: int) -> float:
        """Backoff (before jitter) before the next attempt after ``failures`` consecutive transport failures."""
        return min(self.backoff_s * self.backoff_factor ** max(failures - 1, 0), self.max_backoff_s)

    def wait_s(self, failures: int, retry_after_s: float | None = None, u: float = 0.0) -> float:
        """``max(delay(failures) * (1 - jitter * u), retry_after_s)``, ``u`` in [0, 1) (no lockstep retries)."""
        backoff = self.delay(failures) * (1.0 - self.jitter * min(max(u, 0.0), 1.0))
        return max(backoff, retry_after_s or 0.0)


@dataclass(frozen=True)
class Attempt:
    """One call's outcome. ``error_kind``: None, ``transport``, ``timeout``, ``unavailable``, ``busy`` (HTTP
    429/503), ``rejected`` or ``parse:<ReplyParseError.reason>``."""

    index: int
    error_kind: str | None
    error: str | None
    latency_s: float
    cached: bool = False
    prompt_tokens: int = 0
    completion_tokens: int = 0
    text: str | None = None
    original_latency_s: float | None = None  # a cache hit: the latency of the call that made the entry

    @property
    def ok(self) -> bool:
        return self.error_kind is None


@dataclass(frozen=True)
class Advice:
    """The outcome of ``advise``: a valid reply (the model's or the fallback) and its history."""

    reply: PlannerReply
    fallback: bool
    clamped: dict[str, float] = field(default_factory=dict)
    attempts: tuple[Attempt, ...] = ()
    response: LLMResponse | None = None
    model_spec: str = ""
    choice: str | None = None  # ``choose``: the option's name

    @property
    def latency_s(self) -> float:
        """Wall time spent in calls (cache hits cost their lookup time only)."""
        return sum(a.latency_s for a in self.attempts)

    @property
    def prompt_tokens(self) -> int:
        return sum(a.prompt_tokens for a in self.attempts)

    @property
    def completion_tokens(self) -> int:
        return sum(a.completion_tokens for a in self.attempts)

    @property
    def cached(self) -> bool:
        """True when every attempt was served from the cache."""
        return bool(self.attempts) and all(a.cached for a in self.attempts)

    @property
    def uncached_latency_s(self) -> float:
        """Wall time of the attempts that really called the model (what inference costs now)."""
        return sum(a.latency_s for a in self.attempts if not a.cached)

    @property
    def original_latency_s(self) -> float:
        """What every attempt cost when it was first made (cache hits: their recorded latency)."""
        return sum(a.original_latency_s if a.cached and a.original_latency_s is not None else a.latency_s
                   for a in self.attempts)

    def summary(self) -> dict[str, Any]:
        """A JSON-ready record (for logs and memory banks)."""
        return {
            "model_spec": self.model_spec,
            "reply": self.reply.model_dump(),
            "fallback": self.fallback,
            "clamped": dict(self.clamped),
            "attempts": len(self.attempts),
            "errors": [a.error_kind for a in self.attempts if not a.ok],
            "latency_s": round(self.latency_s, 3),
            "uncached_latency_s": round(self.uncached_latency_s, 3),
            "original_latency_s": round(self.original_latency_s, 3),
            "prompt_tokens": self.prompt_tokens,
            "completion_tokens": self.completion_tokens,
            "live_prompt_tokens": sum(a.prompt_tokens for a in self.attempts if not a.cached),
            "live_completion_tokens": sum(a.completion_tokens for a in self.attempts if not a.cached),
            "cached": self.cached,
            "cached_attempts": sum(int(a.cached) for a in self.attempts),
            **({"choice": self.choice} if self.choice is not None else {}),
        }


def corrective_message(error: ReplyParseError, variant: Variant) -> str:
    """The short user message sent after an invalid reply."""
    keys = [k for k in WIRE_KEYS.values() if variant == "physics" or k != WIRE_KEYS["rationale"]]
    return (
        f"Your reply was not valid ({error}). Reply again with only one JSON object with the keys "
        f"{', '.join(keys)}; all numbers finite and inside the given ranges."
    )


def choice_corrective_message(error: ReplyParseError, names: Sequence[str]) -> str:
    """The short user message sent after an invalid choice reply."""
    return (f"Your reply was not valid ({error}). Reply again with only one JSON object with the key "
            f"{CHOICE_KEY} and one of: {', '.join(names)}.")


T = TypeVar("T")
CacheArg = ResponseCache | None | Literal["default"]


_ERROR_KINDS: Final = ((RequestRejectedError, "rejected"), (BackendUnavailableError, "unavailable"),
                       (LLMTimeoutError, "timeout"), (ServerBusyError, "busy"))


def _transport_kind(exc: LLMTransportError) -> str:
    return next((kind for cls, kind in _ERROR_KINDS if isinstance(exc, cls)), "transport")


class ParamAdvisor:
    """Asks one backend for social-force parameters. ``cache``: ``"default"`` (``ResponseCache()``) or None.
    ``use_schema=False`` sends no JSON schema. ``sleep`` waits out backoff (default ``breaker.wait``, which a
    stopping run interrupts); ``rng`` draws the jitter; ``breaker`` and ``stats`` are run-wide."""

    def __init__(self, backend: LLMBackend | str, *, cache: CacheArg = "default", retry: RetryPolicy | None = None,
                 settings: DecodingSettings | None = None, use_schema: bool = True,
                 fallback_reply: PlannerReply = DEFAULT_REPLY, sleep: Callable[[float], None] | None = None,
                 rng: random.Random | None = None, breaker: CircuitBreaker | None = None) -> None:
        self.backend: LLMBackend = make_backend(backend) if isinstance(backend, str) else backend
        self.cache: ResponseCache | None = ResponseCache() if cache == "default" else cache
        self.retry = retry or RetryPolicy()
        self.settings = settings or DecodingSettings()
        self.use_schema = use_schema
        self.fallback_reply = fallback_reply
        self.breaker = breaker or CircuitBreaker()
        self.stats = RequestStats()
        self._sleep = sleep or self.breaker.wait
        self._rng = rng or random.Random()
        self._rng_lock = threading.Lock()

    def complete(self, messages: Sequence[Message], *, schema: dict[str, Any] | None) -> LLMResponse:
        """One call through the cache (no validation, no retry)."""
        key = ""
        if self.cache is not None:
            identity, origin = backend_identity(self.backend), installed_origin(self.backend.spec)
            key = cache_key(identity if origin is None else f"{identity} [{origin}]", messages, self.settings, schema)
            t0 = time.perf_counter()
            hit = self.cache.get(key)
            if hit is not None:
                return LLMResponse(text=hit.text, parsed=try_parse_json(hit.text), prompt_tokens=hit.prompt_tokens,
                                   completion_tokens=hit.completion_tokens, latency_s=time.perf_counter() - t0,
                                   model_spec=self.backend.spec, cached=True,
                                   extra={"original_latency_s": hit.latency_s})
        resp = self.backend.complete(messages, schema=schema, settings=self.settings, timeout_s=self.retry.timeout_s)
        if self.cache is not None:
            self.cache.put(key, self.backend.spec,
                           CachedEntry(resp.text, resp.prompt_tokens, resp.completion_tokens, resp.latency_s))
        return resp

    def advise(self, messages: Sequence[Message], *, variant: Variant = "physics") -> Advice:
        """Parameters for one prompt; a bad reply falls back, a failed transport raises (module docstring)."""
        schema = reply_json_schema(variant) if self.use_schema else None
        parsed, resp, log = self._ask(messages, schema, parse_reply, lambda exc: corrective_message(exc, variant))
        if parsed is None or resp is None:
            return self._without_valid_reply(log)
        return Advice(reply=parsed.reply, fallback=False, clamped=parsed.clamped, attempts=tuple(log.attempts),
                      response=resp, model_spec=self.backend.spec)

    def choose(self, messages: Sequence[Message], options: Mapping[str, PlannerReply]) -> Advice:
        """One of ``options`` (name -> the answer it stands for): ``Advice.choice`` names it, ``Advice.reply``
        is its answer. No valid name in ``max_attempts``: the first option; a failed transport raises."""
        names = list(options)
        if not names:
            raise ValueError("choose needs at least one option")
        schema = choice_json_schema(names) if self.use_schema else None
        name, resp, log = self._ask(messages, schema, lambda text: parse_choice(text, names),
                                    lambda exc: choice_corrective_message(exc, names))
        if name is None or resp is None:
            return replace(self._without_valid_reply(log), reply=options[names[0]], choice=names[0])
        return Advice(reply=options[name], fallback=False, attempts=tuple(log.attempts), response=resp,
                      model_spec=self.backend.spec, choice=name)

    def _ask(self, messages: Sequence[Message], schema: dict[str, Any] | None, parse: Callable[[str], T],
             corrective: Callable[[ReplyParseError], str]) -> tuple[T | None, LLMResponse | None, _AttemptLog]:
        """Up to ``max_attempts`` calls until ``parse`` accepts a reply: (parsed, its response, the log), or
        (None, None, log). A retry echoes only the last bad reply (the static prefix stays cached)."""
        base = list(messages)
        current = list(base)
        log = _AttemptLog()
        for i in range(self.retry.max_attempts):
            self.breaker.check()
            resp = self._send(i, current, schema, log)
            if resp is None:  # a transport failure (waited) or a rejection (final) is in the log
                if log.attempts[-1].error_kind == "rejected":
                    break  # the same request would be refused again
                continue
            try:
                parsed = parse(resp.text)
            except ReplyParseError as exc:
                log.attempts.append(_response_attempt(i, resp, f"parse:{exc.reason}", str(exc)))
                current = [*base, message("assistant", resp.text[:_ECHO_CHARS]), message("user", corrective(exc))]
                continue
            log.attempts.append(_response_attempt(i, resp))
            return parsed, resp, log
        return None, None, log

    def _send(self, i: int, messages: list[Message], schema: dict[str, Any] | None,
              log: _AttemptLog) -> LLMResponse | None:
        """Attempt ``i``, counted in ``stats``: the response, or None after a rejection or a transport
        failure (recorded in ``log``; the backoff wait is over)."""
        t0 = time.perf_counter()
        self.stats.begin()
        try:
            resp = self.complete(messages, schema=schema)
        except RequestRejectedError as exc:
            self.stats.end(ok=True)  # answered, but without a reply: no latency to count
            self.breaker.record_success()
            log.attempts.append(Attempt(i, "rejected", str(exc), time.perf_counter() - t0))
            return None
        except LLMTransportError as exc:
            self.stats.end(ok=False)
            log.attempts.append(Attempt(i, _transport_kind(exc), str(exc), time.perf_counter() - t0))
            log.transport_failures += 1
            if not self._wait_after_transport_failure(i, exc, log):
                raise
            return None
        except BaseException:
            self.stats.end(ok=False)
            raise
        self.stats.end(ok=True, cached=resp.cached, latency_s=resp.latency_s, prompt_tokens=resp.prompt_tokens,
                       completion_tokens=resp.completion_tokens)
        self.breaker.record_success()
        log.last_response = resp
        return resp

    def _wait_after_transport_failure(self, i: int, exc: LLMTransportError, log: _AttemptLog) -> bool:
        """Backoff before the next attempt; False when the caller re-raises ``exc`` (last attempt, server
        never reachable). Raises ``ServerBusyError`` (``Retry-After`` over the limit), ``RunStoppedError``."""
        retry_after = exc.retry_after_s
        if retry_after is not None and not retry_after <= self.retry.max_retry_after_s:
            raise ServerBusyError(
                f"{exc}; the server asks to wait {retry_after:.0f} s, longer than the "
                f"{self.retry.max_retry_after_s:g} s letspi waits per request: stopping instead of "
                "falling back (run again later; finished results are kept)",
                status=exc.status,
                retry_after_s=retry_after,
            ) from exc
        if i + 1 < self.retry.max_attempts:
            self.breaker.record_failure(exc)  # raises RunStoppedError when the budget is spent
            with self._rng_lock:
                u = self._rng.random()
            self._sleep(self.retry.wait_s(log.transport_failures, retry_after, u))
        elif all(a.error_kind == "unavailable" for a in log.attempts):
            return False
        else:
            self.breaker.record_failure(exc)
        return True

    def _without_valid_reply(self, log: _AttemptLog) -> Advice:
        """After the last attempt: the fallback if the model answered every attempt, else ``RequestFailedError``."""
        failed = [a for a in log.attempts if a.error_kind in TRANSPORT_KINDS]
        if failed:
            kinds = ", ".join(a.error_kind or "" for a in log.attempts)
            raise RequestFailedError(
                f"{self.backend.spec}: no valid reply in {len(log.attempts)} attempts ({kinds}); last transport "
                f"error: {failed[-1].error}")
        return Advice(reply=self.fallback_reply, fallback=True, attempts=tuple(log.attempts),
                      response=log.last_response, model_spec=self.backend.spec)


@dataclass
class _AttemptLog:
    """What ``ParamAdvisor.advise`` has tried for one prompt so far."""

    attempts: list[Attempt] = field(default_factory=list)
    transport_failures: int = 0
    last_response: LLMResponse | None = None


def _response_attempt(i: int, resp: LLMResponse, error_kind: str | None = None, error: str | None = None) -> Attempt:
    """The record of attempt ``i`` that got a response (``error_kind`` ``parse:<reason>`` for an invalid one)."""
    return Attempt(i, error_kind, error, resp.latency_s, resp.cached, resp.prompt_tokens, resp.completion_tokens,
                   resp.text, resp.extra.get("original_latency_s") if resp.cached else None)
