"""Frozen configurations and their content keys: everything that changes an answer is a field.

``Config.key()``: the first 16 hex digits of the SHA-256 of its canonical JSON (sorted keys); cosmetic fields (a
path whose content is fingerprinted elsewhere, a timeout, the cache switch) are recorded but not hashed.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from enum import Enum
from pathlib import Path
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict

KEY_CHARS = 16


def _identity(value: Any) -> Any:
    if isinstance(value, Config):
        return value.identity()
    if isinstance(value, BaseModel):
        return value.model_dump(mode="json")
    if isinstance(value, Enum):
        return value.value
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, Mapping):
        return {str(k): _identity(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_identity(v) for v in value]
    return value


def canonical_json(value: Any) -> str:
    """Sorted-key, whitespace-free JSON: the text that is hashed."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False)


def key_of(identity: Any) -> str:
    """The key of an identity dict (``Config.identity()``)."""
    return hashlib.sha256(canonical_json(identity).encode("utf-8")).hexdigest()[:KEY_CHARS]


class Config(BaseModel):
    """Base of every configuration: frozen, no unknown fields, a content key."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    #: fields that locate or label but cannot change an answer (recorded, not hashed)
    cosmetic: ClassVar[frozenset[str]] = frozenset()
    #: fields left out of the key while they are None: a feature added later, off, keeps the keys it had
    omitted_when_none: ClassVar[frozenset[str]] = frozenset()

    def identity(self) -> dict[str, Any]:
        """What the key hashes: every non-cosmetic field, nested configurations by their identity."""
        return {name: _identity(getattr(self, name)) for name in type(self).model_fields
                if name not in self.cosmetic and not (name in self.omitted_when_none and getattr(self, name) is None)}

    def key(self) -> str:
        """16 hex digits identifying this configuration's answers."""
        return key_of(self.identity())

    def record(self) -> dict[str, Any]:
        """Everything, cosmetic fields included (what ``run.json`` stores)."""
        return self.model_dump(mode="json")


def diff(old: Mapping[str, Any], new: Mapping[str, Any], prefix: str = "") -> list[str]:
    """Dotted field paths whose values differ between two identity dicts, with both values."""
    out: list[str] = []
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k, "<absent>"), new.get(k, "<absent>")
        path = f"{prefix}{k}"
        if isinstance(a, Mapping) and isinstance(b, Mapping):
            out += diff(a, b, prefix=f"{path}.")
        elif a != b:
            out.append(f"{path}: {_short(a)} -> {_short(b)}")
    return out


def _short(value: Any) -> str:
    text = json.dumps(value, sort_keys=True) if not isinstance(value, str) else value
    return text if len(text) <= 60 else text[:57] + "..."
