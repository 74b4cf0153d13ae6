"""Backend spec strings (``PREFIX:MODEL``) and the one table of backend kinds (``BackendKind``) they name.

Parsing, the valid-forms error, default concurrency and ``letspi llm backends`` derive from the table.
Installed packages add kinds through the ``letspi.llm_backends`` entry-point group (name = prefix), read
only for an unknown prefix or when listing.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Final

from letspi.llm.backends.llamacpp import LlamaCppBackend
from letspi.llm.backends.ollama import OllamaBackend
from letspi.llm.backends.openai_compat import OpenAICompatBackend
from letspi.llm.backends.scripted import ScriptedBackend, default_reply_text
from letspi.llm.models import locate_model
from letspi.llm.types import LLMBackend, LLMError, UnknownBackendError
from letspi.suggest import unknown

#: the entry-point group through which installed packages add backend kinds
ENTRY_POINT_GROUP: Final = "letspi.llm_backends"
#: where to read how to write one
PLUGIN_DOC: Final = "docs/architecture.md#add-an-llm-backend"
_PREFIX_RE: Final = re.compile(r"^[a-z][a-z0-9_-]*$")
_URL_RE: Final = re.compile(r"^https?://[^\s/]+(/\S*)?$")


@dataclass(frozen=True)
class BackendSpec:
    """A parsed spec: backend kind, model and (openai only) base URL."""

    kind: str
    model: str
    base_url: str | None = None

    def __str__(self) -> str:
        return f"{self.kind}:{self.model}" + (f"@{self.base_url}" if self.base_url else "")


@dataclass(frozen=True)
class BackendKind:
    """One backend kind: ``factory(spec, options)`` builds the backend; ``forms``: the documented spec forms;
    ``default_concurrency``: scenarios in flight unless ``--concurrency`` says otherwise; ``local_weights(spec)``:
    the weights file a spec runs, whose SHA-256 enters the LLM key (None: a server's model, keyed by name);
    ``parse(rest)``: ``(model, base_url)`` of the text after the prefix, or ``ValueError`` saying why."""

    prefix: str
    factory: Callable[[BackendSpec, dict[str, Any]], LLMBackend]
    forms: tuple[str, ...]
    doc: str
    default_concurrency: int = 1
    local_weights: Callable[[BackendSpec], Path] | None = None
    parse: Callable[[str], tuple[str, str | None]] | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.prefix, str) or not _PREFIX_RE.match(self.prefix):
            raise ValueError(f"backend prefix {self.prefix!r} must be lowercase letters, digits, '-' or '_'")
        if not callable(self.factory):
            raise ValueError(f"backend {self.prefix!r}: factory must be callable (spec, options) -> LLMBackend")
        if not self.forms or any(not str(f).startswith(f"{self.prefix}:") for f in self.forms):
            raise ValueError(f"backend {self.prefix!r}: forms must be spec forms starting with {self.prefix + ':'!r}")
        if isinstance(self.default_concurrency, bool) or not isinstance(self.default_concurrency, int) \
                or self.default_concurrency < 1:
            raise ValueError(f"backend {self.prefix!r}: default_concurrency must be an integer >= 1")


def _openai_model(rest: str) -> tuple[str, str | None]:
    if "@" not in rest:
        return rest, None
    model, _, base_url = rest.rpartition("@")
    if not model or not _URL_RE.match(base_url):
        raise ValueError(f"base URL {base_url!r} must look like http://host:port/v1")
    return model, base_url


def _scripted_model(rest: str) -> tuple[str, str | None]:
    if rest != "default":
        raise ValueError("only scripted:default can be built from a spec")
    return rest, None


#: the built-in kinds, in listing order
BUILT_IN: Final[tuple[BackendKind, ...]] = (
    BackendKind(
        "llamacpp", lambda s, o: LlamaCppBackend(s.model, **o),
        ("llamacpp:gemma3-270m", "llamacpp:smollm2-135m", "llamacpp:smollm2-135m-letspi",
         "llamacpp:/path/to/model.gguf"),
        "embedded llama.cpp model: an embedded name (letspi llm models) or a local GGUF file",
        default_concurrency=1,  # one reply at a time: a lock around its KV cache
        local_weights=lambda s: locate_model(s.model)),
    BackendKind(
        "ollama", lambda s, o: OllamaBackend(s.model, **o), ("ollama:MODEL (e.g. ollama:llama3.1:8b)",),
        "Ollama /api/chat ($OLLAMA_HOST)", default_concurrency=8),
    BackendKind(
        "openai",
        lambda s, o: OpenAICompatBackend(s.model, base_url=s.base_url or o.pop("base_url", None), **o),
        ("openai:MODEL[@http://host:port/v1]",),
        "OpenAI-compatible /chat/completions (base URL after @, else $OPENAI_BASE_URL)", default_concurrency=8,
        parse=_openai_model),
    BackendKind(
        "scripted", lambda s, o: ScriptedBackend(default=default_reply_text(), name=s.model, **o),
        ("scripted:default",), "test double answering DEFAULT_REPLY (no model)",
        default_concurrency=1,  # replays its script in call order
        parse=_scripted_model),
)
_BUILT_IN: Final[dict[str, BackendKind]] = {k.prefix: k for k in BUILT_IN}


class BackendKindError(UnknownBackendError):
    """A backend kind from an installed package that cannot be used (the message names it and why)."""


@dataclass(frozen=True)
class InstalledBackends:
    """What ``ENTRY_POINT_GROUP`` offers: the usable kinds by prefix, where each comes from (prefix ->
    "package VERSION") and one line per entry point left out (by entry-point name)."""

    kinds: dict[str, BackendKind]
    origins: dict[str, str]
    problems: dict[str, str]


def _checked(obj: object, name: str, where: str, taken: dict[str, BackendKind]) -> BackendKind:
    if not isinstance(obj, BackendKind):
        what = "a class" if isinstance(obj, type) else f"a {type(obj).__name__}"
        raise BackendKindError(f"{where} is {what}, not a letspi BackendKind ({PLUGIN_DOC})")
    if obj.prefix != name:
        raise BackendKindError(f"{where}: the entry-point name must be the kind's prefix {obj.prefix!r}")
    if obj.prefix in taken:
        raise BackendKindError(f"{where}: backend prefix {obj.prefix!r} exists already")
    return obj


@functools.cache
def installed_backends() -> InstalledBackends:
    """The kinds installed packages name in ``ENTRY_POINT_GROUP``, checked; read once per process."""
    kinds: dict[str, BackendKind] = {}
    origins: dict[str, str] = {}
    problems: dict[str, str] = {}
    for ep in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        dist = getattr(ep, "dist", None)
        package = f"{dist.name} {dist.version}" if dist is not None else "a package"
        where = f"LLM backend {ep.value} (entry point {ep.name!r} of {package})"
        try:
            kind = _checked(ep.load(), ep.name, where, {**_BUILT_IN, **kinds})
        except BackendKindError as exc:
            problems[ep.name] = str(exc)
            continue
        except Exception as exc:  # a broken plug-in must not break letspi: it is reported
            problems[ep.name] = f"{where}: {type(exc).__name__}: {exc}"
            continue
        kinds[kind.prefix] = kind
        origins[kind.prefix] = package
    return InstalledBackends(kinds, origins, problems)


def _loaded() -> dict[str, BackendKind]:
    """The built-in kinds and the installed ones when they have been read (never reads them)."""
    if installed_backends.cache_info().currsize == 0:
        return dict(_BUILT_IN)
    return {**_BUILT_IN, **installed_backends().kinds}


def backend_table() -> tuple[BackendKind, ...]:
    """Every kind: the built-in ones, then the installed ones (reads the entry points)."""
    return (*BUILT_IN, *installed_backends().kinds.values())


def backend_origin(prefix: str) -> str:
    """Where a kind comes from: "built in", "package VERSION" or "unknown"."""
    return "built in" if prefix in _BUILT_IN else installed_backends().origins.get(prefix, "unknown")


def installed_origin(spec: str) -> str | None:
    """"package VERSION" of the installed kind a spec (or prefix) names; None for a built-in or unknown one."""
    prefix = str(spec).partition(":")[0].strip().lower()
    return None if prefix in _BUILT_IN else installed_backends().origins.get(prefix)


def backend_names() -> tuple[str, ...]:
    """The built-in backend prefixes."""
    return tuple(_BUILT_IN)


def _bad(spec: str, why: str) -> UnknownBackendError:
    forms = "\n  ".join(f for kind in _loaded().values() for f in kind.forms)
    return UnknownBackendError(f"invalid LLM spec {spec!r}: {why}. Valid forms:\n  {forms}")


def backend_kind(prefix: str, spec: str | None = None) -> BackendKind:
    """The kind of ``prefix``: built in, else installed (reads the entry points once); ``UnknownBackendError``
    listing the valid forms (or why an installed kind of that name is left out) otherwise."""
    kind = _BUILT_IN.get(prefix)
    if kind is not None:
        return kind
    installed = installed_backends()
    if prefix in installed.kinds:
        return installed.kinds[prefix]
    if prefix in installed.problems:
        raise BackendKindError(installed.problems[prefix])
    raise _bad(spec or f"{prefix}:", unknown("backend", prefix, _loaded()))


def parse_spec(spec: str) -> BackendSpec:
    """Parse a spec string; raises ``UnknownBackendError`` listing the valid forms."""
    if not isinstance(spec, str) or ":" not in spec:
        raise _bad(str(spec), "expected BACKEND:MODEL")
    prefix, _, rest = spec.strip().partition(":")
    kind = backend_kind(prefix.lower(), spec)
    rest = rest.strip()
    if not rest:
        raise _bad(spec, "missing model name")
    base_url: str | None = None
    if kind.parse is not None:
        try:
            rest, base_url = kind.parse(rest)
        except ValueError as exc:
            raise _bad(spec, str(exc)) from None
    return BackendSpec(kind=kind.prefix, model=rest, base_url=base_url)


def default_concurrency(spec: str | BackendSpec) -> int:
    """Scenarios a run keeps in flight against ``spec`` unless ``--concurrency`` says otherwise (unknown kind: 1)."""
    prefix = spec.kind if isinstance(spec, BackendSpec) else str(spec).partition(":")[0].strip().lower()
    kind = _BUILT_IN.get(prefix) or installed_backends().kinds.get(prefix)
    return kind.default_concurrency if kind is not None else 1


def make_backend(spec: str | BackendSpec, **options: Any) -> LLMBackend:
    """Build a backend from a spec; ``options`` go to its constructor. Raises ``LLMConfigError`` subclasses at
    once for unknown backends, missing packages or models; ``BackendKindError`` naming the package when an
    installed kind's factory fails."""
    parsed = parse_spec(spec) if isinstance(spec, str) else spec
    kind = backend_kind(parsed.kind, str(parsed))
    if kind.prefix in _BUILT_IN:
        return kind.factory(parsed, dict(options))
    origin = backend_origin(kind.prefix)
    try:
        backend = kind.factory(parsed, dict(options))
    except LLMError:
        raise
    except Exception as exc:  # a plug-in's bug, named as such
        raise BackendKindError(f"{parsed}: the backend of {origin} failed to start: {type(exc).__name__}: {exc}") \
            from exc
    if not isinstance(backend, LLMBackend):
        raise BackendKindError(f"{parsed}: the backend of {origin} returned a {type(backend).__name__}, "
                               "not an LLMBackend (a spec property and complete())")
    if not str(backend.spec).startswith(f"{kind.prefix}:"):  # the cache and the run records go by its spec
        raise BackendKindError(f"{parsed}: the backend of {origin} has spec {backend.spec!r}, which does not start "
                               f"with {kind.prefix + ':'!r}")
    return backend
