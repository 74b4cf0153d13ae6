"""An LLM backend for letspi in its own package: ``echo:NAME`` answers from the request's JSON schema."""

from typing import Any

from letspi.plugin import BackendKind, BackendSpec, LLMBackend
from letspi_echo_backend.backend import EchoBackend, reply_from_schema


def _build(spec: BackendSpec, options: dict[str, Any]) -> LLMBackend:
    return EchoBackend(spec.model, **options)


KIND = BackendKind(
    "echo", _build, ("echo:NAME (NAME: the option to choose when offered)",),
    "answers from the request's JSON schema, without a model (example plug-in)",
    default_concurrency=4,  # no shared state: answers many requests at once
)

__all__ = ["KIND", "EchoBackend", "reply_from_schema"]
