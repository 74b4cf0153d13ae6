"""Backend spec strings, parsed and built: ``llamacpp:NAME`` (an embedded model, ``letspi.llm.models``) or
``llamacpp:/path/model.gguf``; ``ollama:MODEL`` (``$OLLAMA_HOST``); ``openai:MODEL[@http://host:port/v1]``
(else ``$OPENAI_BASE_URL``); ``scripted:default`` (a test double answering ``DEFAULT_REPLY``).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Final

from letspi.llm.backends.llamacpp import LlamaCppBackend
from letspi.llm.backends.ollama import OllamaBackend
from letspi.llm.backends.openai_compat import OpenAICompatBackend
from letspi.llm.backends.scripted import ScriptedBackend, default_reply_text
from letspi.llm.types import LLMBackend, UnknownBackendError

VALID_FORMS: Final = (
    "llamacpp:gemma3-270m",
    "llamacpp:smollm2-135m",
    "llamacpp:smollm2-135m-letspi",
    "llamacpp:/path/to/model.gguf",
    "ollama:MODEL (e.g. ollama:llama3.1:8b)",
    "openai:MODEL[@http://host:port/v1]",
    "scripted:default",
)
_URL_RE: Final = re.compile(r"^https?://[^\s/]+(/\S*)?$")


@dataclass(frozen=True)
class BackendSpec:
    """A parsed spec: backend kind, model and (openai only) base URL."""

    kind: str
    model: str
    base_url: str | None = None

    def __str__(self) -> str:
        return f"{self.kind}:{self.model}" + (f"@{self.base_url}" if self.base_url else "")


def _bad(spec: str, why: str) -> UnknownBackendError:
    forms = "\n  ".join(VALID_FORMS)
    return UnknownBackendError(f"invalid LLM spec {spec!r}: {why}. Valid forms:\n  {forms}")


def parse_spec(spec: str) -> BackendSpec:
    """Parse a spec string; raises ``UnknownBackendError`` listing the valid forms."""
    if not isinstance(spec, str) or ":" not in spec:
        raise _bad(str(spec), "expected BACKEND:MODEL")
    kind, _, rest = spec.strip().partition(":")
    kind = kind.lower()
    if kind not in _FACTORIES:
        raise _bad(spec, f"unknown backend {kind!r} (known: {', '.join(_FACTORIES)})")
    rest = rest.strip()
    if not rest:
        raise _bad(spec, "missing model name")
    base_url: str | None = None
    if kind == "openai" and "@" in rest:
        model, _, base_url = rest.rpartition("@")
        if not model or not _URL_RE.match(base_url):
            raise _bad(spec, f"base URL {base_url!r} must look like http://host:port/v1")
        rest = model
    elif kind == "scripted" and rest != "default":
        raise _bad(spec, "only scripted:default can be built from a spec")
    return BackendSpec(kind=kind, model=rest, base_url=base_url)


def _llamacpp(s: BackendSpec, options: dict[str, Any]) -> LLMBackend:
    return LlamaCppBackend(s.model, **options)


def _ollama(s: BackendSpec, options: dict[str, Any]) -> LLMBackend:
    return OllamaBackend(s.model, **options)


def _openai(s: BackendSpec, options: dict[str, Any]) -> LLMBackend:
    return OpenAICompatBackend(s.model, base_url=s.base_url or options.pop("base_url", None), **options)


def _scripted(s: BackendSpec, options: dict[str, Any]) -> LLMBackend:
    return ScriptedBackend(default=default_reply_text(), name=s.model, **options)


_FACTORIES: Final[dict[str, Callable[[BackendSpec, dict[str, Any]], LLMBackend]]] = {
    "llamacpp": _llamacpp,
    "ollama": _ollama,
    "openai": _openai,
    "scripted": _scripted,
}


def backend_names() -> tuple[str, ...]:
    """Known backend kinds."""
    return tuple(_FACTORIES)


#: Scenarios in flight by default per backend kind: the embedded model generates one reply at a time
#: (a lock around its KV cache), a scripted backend replays its script in call order; servers
#: (Ollama with ``OLLAMA_NUM_PARALLEL``, llama.cpp ``-np``, vLLM) answer many requests at once.
DEFAULT_CONCURRENCY: Final[dict[str, int]] = {"llamacpp": 1, "scripted": 1, "ollama": 8, "openai": 8}


def default_concurrency(spec: str | BackendSpec) -> int:
    """Scenarios a run keeps in flight against ``spec`` unless ``--concurrency`` says otherwise (unknown kind: 1)."""
    kind = spec.kind if isinstance(spec, BackendSpec) else str(spec).partition(":")[0].strip().lower()
    return DEFAULT_CONCURRENCY.get(kind, 1)


def make_backend(spec: str | BackendSpec, **options: Any) -> LLMBackend:
    """Build a backend from a spec; ``options`` go to its constructor. Raises ``LLMConfigError`` subclasses at
    once for unknown backends, missing packages or models."""
    parsed = parse_spec(spec) if isinstance(spec, str) else spec
    return _FACTORIES[parsed.kind](parsed, dict(options))
