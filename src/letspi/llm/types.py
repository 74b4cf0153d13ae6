"""Core types of the LLM layer: messages, decoding settings, responses, errors, the backend protocol.

Errors: ``LLMConfigError`` (setup wrong: raised at once, never retried, so a typo cannot turn a run into
fallbacks); ``LLMTransportError`` (one call failed: retried with backoff); ``ReplyParseError`` (invalid
answer: retried with a corrective message, then the fallback).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Literal, Protocol, TypedDict, runtime_checkable

Role = Literal["system", "user", "assistant"]


class Message(TypedDict):
    """One chat message, in the shape every chat API accepts."""

    role: Role
    content: str


def message(role: Role, content: str) -> Message:
    """Build a ``Message`` (a typed shorthand)."""
    return {"role": role, "content": content}


@dataclass(frozen=True)
class DecodingSettings:
    """Sampling settings sent with every call; part of the cache key. Temperature 0 and a fixed seed make
    replies reproducible (paper §IV)."""

    temperature: float = 0.0
    seed: int = 0
    max_tokens: int = 320

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class LLMResponse:
    """What a backend returns for one call. ``parsed``: the reply's JSON object as ``letspi.llm.parse``
    chooses it (values not validated), else None."""

    text: str
    parsed: dict[str, Any] | None
    prompt_tokens: int
    completion_tokens: int
    latency_s: float
    model_spec: str
    cached: bool = False
    extra: dict[str, Any] = field(default_factory=dict)


@runtime_checkable
class LLMBackend(Protocol):
    """A chat model: messages in, one ``LLMResponse`` out. Raises ``LLMConfigError`` for setup problems and
    ``LLMTransportError`` for failures of one call; never validates the reply."""

    @property
    def spec(self) -> str:
        """The canonical spec string (``llamacpp:gemma3-270m``, ``ollama:llama3.1:8b``, ...)."""
        ...

    def complete(self, messages: Sequence[Message], *, schema: dict[str, Any] | None, settings: DecodingSettings,
                 timeout_s: float) -> LLMResponse:
        """Send ``messages``; constrain the reply to ``schema`` (a JSON schema) when not None."""
        ...


@runtime_checkable
class KeyedBackend(Protocol):
    """A backend whose replies depend on more than its spec (local weights, adapter, runtime, plug-in version):
    ``cache_identity`` names it all (the response cache keys on it)."""

    @property
    def cache_identity(self) -> str: ...


@runtime_checkable
class LoadingBackend(Protocol):
    """A backend that loads weights in this process: ``load()`` does it now, so that callers time loading apart."""

    def load(self) -> None: ...


class LLMError(Exception):
    """Base class of every error raised by ``letspi.llm``."""


class LLMConfigError(LLMError):
    """The configuration is wrong; retrying cannot help."""


class UnknownBackendError(LLMConfigError):
    """Malformed spec string or unknown backend name."""


class MissingDependencyError(LLMConfigError):
    """An optional package (llama-cpp-python, a model package) is not installed."""


class ModelNotFoundError(LLMConfigError):
    """The server or the local install does not have the requested model."""


class ModelSelfCheckError(LLMConfigError):
    """Batched prompt evaluation disagrees with token by token and ``LETSPI_LLAMA_SELF_CHECK=strict``."""


class LlamaFaultError(LLMConfigError):
    """llama.cpp faults (SIGILL, SIGSEGV, ...) running this model format on this CPU (caught by the probe in a
    child process); the message names the format, the CPU feature and what to do."""


class ResponseCacheError(LLMConfigError):
    """The response cache file cannot be opened, read or written; the message names the file and what to do."""


class LLMTransportError(LLMError):
    """One call failed in transport (connection, HTTP 5xx, malformed envelope); retryable. ``status``: the
    HTTP status, if any; ``retry_after_s``: the server's ``Retry-After`` [s], honoured before the next attempt."""

    def __init__(self, message: str, *, status: int | None = None, retry_after_s: float | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.retry_after_s = retry_after_s

    def __reduce__(self) -> tuple[Any, ...]:
        # picklable (worker processes) despite the keyword-only fields
        return (_rebuild_transport_error, (type(self), str(self), self.status, self.retry_after_s))


def _rebuild_transport_error(cls: type[LLMTransportError], message: str, status: int | None,
                             retry_after_s: float | None) -> LLMTransportError:
    return cls(message, status=status, retry_after_s=retry_after_s)


class LLMTimeoutError(LLMTransportError):
    """One call exceeded its timeout."""


class ServerBusyError(LLMTransportError):
    """HTTP 429 or 503: retried after ``max(backoff, retry_after_s)``; raised (stops the run) when the wait
    asked exceeds ``RetryPolicy.max_retry_after_s``."""


class BackendUnavailableError(LLMTransportError):
    """The server could not be reached (connection refused, DNS); raised when every attempt of a call hit it."""


class RequestRejectedError(LLMTransportError):
    """The server refused this one request (HTTP 4xx other than 401/403/404/429, a prompt over the context):
    not retried, not a transport failure; the request falls back."""


class RequestFailedError(LLMTransportError):
    """No valid reply in all attempts, at least one a transport failure: the scenario is not stored (a rerun
    retries it) and the run goes on."""


class RunStoppedError(BackendUnavailableError):
    """The run's circuit breaker tripped (``letspi.llm.guard``): every request stops; the message names the
    first cause. Finished scenarios are stored."""


class ReplyParseError(LLMError, ValueError):
    """The reply is not a valid parameter set. ``reason`` is a short machine-readable code."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail
