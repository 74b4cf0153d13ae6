"""Core types of the LLM layer: messages, decoding settings, responses, errors, the backend protocol.

Error taxonomy (what the caller does with it):

* ``LLMConfigError`` and subclasses: the setup is wrong (unknown backend, malformed spec, missing
  package or model, authentication). Raised immediately, never retried: a long run must not
  silently turn every scenario into a fallback because of a typo.
* ``LLMTransportError`` and subclasses: one call failed (HTTP 5xx, reset connection, timeout,
  HTTP 429/503 ``ServerBusyError``). Retried with exponential backoff and jitter, never sooner
  than the server's ``Retry-After``; after the last attempt the advisor falls back to default
  parameters. Two stop the run instead (raised out of ``ParamAdvisor.advise``): a
  ``BackendUnavailableError`` on every attempt (dead server), and a ``ServerBusyError`` whose
  ``Retry-After`` exceeds the policy's ``max_retry_after_s``.
  A request whose attempts were spent without a valid reply and at least one of them failed in
  transport raises ``RequestFailedError``: nothing is stored for that scenario and a rerun retries it
  (a fallback means the *model* had every attempt and never answered validly).
  ``RequestRejectedError`` (the server refused this one request, e.g. a prompt longer than the
  context; HTTP 4xx other than 401/403/404/429) is not a transport failure: retrying cannot help,
  the request falls back at once.
* Run level (``letspi.llm.guard``): ``RunStoppedError`` when the shared circuit breaker trips
  (a bounded number of consecutive transport failures across all requests in flight);
  ``letspi.execution.ordered.ScenariosFailedError`` at the end of a run that left scenarios unstored.
* ``ReplyParseError``: the model answered but the reply is not a valid parameter set. Retried with
  a corrective message, then the fallback.
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
    """Sampling settings sent with every call; part of the cache key.

    Temperature 0 and a fixed seed make replies reproducible (paper §IV: temperature 0).
    ``max_tokens`` bounds the reply: output tokens dominate latency on small machines.
    """

    temperature: float = 0.0
    seed: int = 0
    max_tokens: int = 320

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class LLMResponse:
    """What a backend returns for one call.

    ``parsed`` is the reply's JSON object as ``letspi.llm.parse`` chooses it (the last complete
    one; no validation of its values: that is ``parse_reply``'s job), else ``None``.
    """

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
    """A chat model: messages in, one ``LLMResponse`` out.

    Implementations raise ``LLMConfigError`` for setup problems and ``LLMTransportError`` for
    failures of one call; they never validate the reply's content.
    """

    @property
    def spec(self) -> str:
        """The canonical spec string (``llamacpp:gemma3-270m``, ``ollama:llama3.1:8b``, ...)."""
        ...

    def complete(
        self,
        messages: Sequence[Message],
        *,
        schema: dict[str, Any] | None,
        settings: DecodingSettings,
        timeout_s: float,
    ) -> LLMResponse:
        """Send ``messages``; constrain the reply to ``schema`` (a JSON schema) when not None."""
        ...


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
    """The loaded model's batched prompt evaluation disagrees with token-by-token evaluation and the
    self-check was asked to refuse rather than fall back (``LETSPI_LLAMA_SELF_CHECK=strict``)."""


class LlamaFaultError(LLMConfigError):
    """llama.cpp kills the process (SIGILL, SIGSEGV, ...) running this model format on this CPU; the probe
    (``letspi.llm.backends.llamacpp_open``) caught it in a child process. The message names the format, the
    CPU feature and what to do."""


class ResponseCacheError(LLMConfigError):
    """The response cache file cannot be opened, read or written (corrupted file, full disk,
    unwritable directory). The message names the file and what to do."""


class LLMTransportError(LLMError):
    """One call failed in transport (connection, HTTP 5xx, malformed envelope); retryable.

    ``status`` is the HTTP status when the server answered; ``retry_after_s`` the delay the
    server asked for in a ``Retry-After`` header (seconds, parsed from seconds or an HTTP date),
    which the advisor honours before that request's next attempt.
    """

    def __init__(self, message: str, *, status: int | None = None, retry_after_s: float | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.retry_after_s = retry_after_s

    def __reduce__(self) -> tuple[Any, ...]:
        # picklable (worker processes) despite the keyword-only fields
        return (_rebuild_transport_error, (type(self), str(self), self.status, self.retry_after_s))


def _rebuild_transport_error(
    cls: type[LLMTransportError], message: str, status: int | None, retry_after_s: float | None
) -> LLMTransportError:
    return cls(message, status=status, retry_after_s=retry_after_s)


class LLMTimeoutError(LLMTransportError):
    """One call exceeded its timeout."""


class ServerBusyError(LLMTransportError):
    """HTTP 429 (rate limited) or 503 (overloaded, loading): the server is up but asks us to wait.

    Retried after ``max(backoff, retry_after_s)``. If the server asks for a longer wait than
    ``RetryPolicy.max_retry_after_s`` the advisor raises this error instead of falling back.
    """


class BackendUnavailableError(LLMTransportError):
    """The server could not be reached at all (connection refused, DNS).

    Retried like any transport error, but if *every* attempt of a call hit it the advisor raises
    it instead of falling back: a dead server is a setup problem, not one bad reply.
    """


class RequestRejectedError(LLMTransportError):
    """The server answered but refused this one request (HTTP 4xx other than 401/403/404/429, or
    the embedded model could not evaluate the prompt): deterministic, so it is not retried and the
    request falls back; it does not count as a transport failure."""


class RequestFailedError(LLMTransportError):
    """A request spent its attempts without a valid reply and at least one attempt failed in
    transport. The scenario is not stored (so a rerun retries it) and the run goes on; the run's
    circuit breaker decides when too many failures stop it."""


class RunStoppedError(BackendUnavailableError):
    """The run's circuit breaker tripped: too many consecutive transport failures across all requests
    in flight (or a dead server, or one request that could not be retried). Every request of the run
    stops with this error; the message names the first cause. Finished scenarios are stored."""


class ReplyParseError(LLMError, ValueError):
    """The reply is not a valid parameter set. ``reason`` is a short machine-readable code."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail
