"""Robust parsing of model replies into a ``PlannerReply``.

Policy (documented here, tested in ``tests/test_llm_parse.py``):

* ``<think>...</think>`` blocks are removed; a stray ``</think>`` drops everything before it
  (some chat templates open the block themselves); an unterminated ``<think>`` drops everything
  after it (unfinished reasoning is not an answer).
* Code fences and prose around the JSON are ignored: the parser scans for JSON objects and takes
  the first one that holds at least one known key (else the first object, which then fails as
  ``missing_keys``). One level of nesting is merged (``{"params": {...}, "goal": {...}}``).
  Trailing commas are repaired as a last resort.
* Keys: the short wire keys, the long names and common variants are accepted, case and
  punctuation insensitive (``tau``, ``tau_s``, ``k_boundary``, ``k_bd``, ``lon_factor``...).
  Unknown keys are ignored (reported in ``ignored_keys``).
* Values: JSON numbers or numeric strings (``"12.5"``). Booleans, null, lists, NaN and infinities
  are rejected.
* **Missing numeric keys make the reply invalid** (``missing_keys``) rather than being filled
  with defaults: a silently filled parameter would look like the model's choice. The advisor
  re-asks, and only uses ``DEFAULT_REPLY`` as a whole, flagged ``fallback=True``. The rationale
  is optional.
* Out-of-range values are clamped to ``FIELD_RANGES``; ``ParsedReply.clamped`` records each
  clamped field with the value the model gave.

``parse_reply`` either returns a ``ParsedReply`` or raises ``ReplyParseError``; nothing else
(fuzzed with hypothesis).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Final

from letspi.llm.schema import FIELD_RANGES, NUMERIC_FIELDS, PlannerReply
from letspi.llm.types import ReplyParseError

#: Longer replies are cut before scanning (the scan is quadratic in the number of braces).
MAX_REPLY_CHARS: Final = 50_000
_MAX_RATIONALE_CHARS: Final = 2_000

_ALIASES: Final[dict[str, str]] = {
    alias: name
    for name, aliases in {
        "tau_s": ("tau", "taus", "relaxationtime"),
        "k_np": ("knp", "kpreceding"),
        "k_nf": ("knf", "kfollowing"),
        "k_nl": ("knl", "klateral"),
        "k_boundary": ("kbd", "kb", "kboundary", "kbound"),
        "k_cline": ("kcl", "kc", "kcline", "kclines", "kcenterline", "kcentreline"),
        "lon_factor": ("lon", "lonfactor", "longitudinal", "longitudinalfactor"),
        "lane_factor": ("lane", "lanefactor", "lat", "lateral", "lateralfactor"),
        "rationale": ("why", "rationale", "reason", "reasoning", "explanation"),
    }.items()
    for alias in aliases
}
_NUMBER_RE: Final = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")
_THINK_BLOCK_RE: Final = re.compile(r"<think>.*?</think>", re.DOTALL | re.IGNORECASE)
_TRAILING_COMMA_RE: Final = re.compile(r",\s*([}\]])")
_DECODER: Final = json.JSONDecoder()


@dataclass(frozen=True)
class ParsedReply:
    """A valid reply plus what the parser had to do to get it."""

    reply: PlannerReply
    clamped: dict[str, float] = field(default_factory=dict)
    ignored_keys: tuple[str, ...] = ()


def canonical_key(key: str) -> str | None:
    """Canonical field name for a reply key, or None if unknown."""
    norm = re.sub(r"[^a-z0-9]", "", key.lower().replace("τ", "tau"))
    return _ALIASES.get(norm)


def strip_reasoning(text: str) -> str:
    """Remove ``<think>`` reasoning (complete, stray-closing and unterminated blocks)."""
    text = _THINK_BLOCK_RE.sub("", text)
    low = text.lower()
    close = low.rfind("</think>")
    if close >= 0:
        text = text[close + len("</think>") :]
        low = text.lower()
    opened = low.find("<think>")
    if opened >= 0:
        text = text[:opened]
    return text


def _known_keys(obj: Mapping[str, Any]) -> int:
    return sum(1 for k in obj if isinstance(k, str) and canonical_key(k) is not None)


def _scan_objects(text: str) -> list[dict[str, Any]]:
    """Every JSON object that decodes starting at some ``{`` (outermost first), in text order."""
    found: list[dict[str, Any]] = []
    pos = text.find("{")
    while pos >= 0:
        try:
            obj, _end = _DECODER.raw_decode(text, pos)
        except (ValueError, RecursionError):
            # JSONDecodeError, over-long ints, absurd nesting: not an object here.
            obj = None
        if isinstance(obj, dict):
            found.append(obj)
            if _known_keys(obj) or any(isinstance(v, dict) and _known_keys(v) for v in obj.values()):
                break  # good enough: stop scanning
        pos = text.find("{", pos + 1)
    return found


def extract_json_object(text: str) -> dict[str, Any]:
    """The reply's JSON object (see module docstring); raises ``ReplyParseError('no_json')``."""
    if not isinstance(text, str):
        raise ReplyParseError("bad_type", f"reply must be text, got {type(text).__name__}")
    body = strip_reasoning(text[:MAX_REPLY_CHARS])
    for candidate in (body, _TRAILING_COMMA_RE.sub(r"\1", body)):
        objects = _scan_objects(candidate)
        for obj in objects:
            if _known_keys(obj) or any(isinstance(v, dict) and _known_keys(v) for v in obj.values()):
                return obj
        if objects:
            return objects[0]
    raise ReplyParseError("no_json", "no JSON object found in the reply")


def _to_float(name: str, value: Any) -> float:
    if isinstance(value, bool) or value is None:
        raise ReplyParseError("bad_value", f"{name} must be a number, got {value!r}")
    if isinstance(value, int | float):
        try:
            x = float(value)
        except OverflowError:
            raise ReplyParseError("non_finite", f"{name} is too large") from None
    elif isinstance(value, str):
        s = value.strip()
        if not _NUMBER_RE.fullmatch(s):
            raise ReplyParseError("bad_value", f"{name} must be a number, got {value[:40]!r}")
        x = float(s)  # cannot raise: the regex admits only plain decimal literals
    else:
        raise ReplyParseError("bad_value", f"{name} must be a number, got {type(value).__name__}")
    if not math.isfinite(x):
        raise ReplyParseError("non_finite", f"{name} is not finite ({value!r})")
    return x


def _rationale_text(value: Any) -> str:
    if isinstance(value, str):
        text = value
    elif isinstance(value, list) and all(isinstance(v, str) for v in value):
        text = " ".join(value)
    else:
        try:
            text = json.dumps(value, ensure_ascii=False)
        except (TypeError, ValueError):
            text = str(value)
    return text.strip()[:_MAX_RATIONALE_CHARS]


def _flatten(obj: Mapping[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """Canonical name -> raw value, merging one level of nested objects; plus ignored keys."""
    values: dict[str, Any] = {}
    ignored: list[str] = []
    nested: list[Mapping[str, Any]] = []
    for key, value in obj.items():
        name = canonical_key(key) if isinstance(key, str) else None
        if name is None:
            if isinstance(value, dict) and _known_keys(value):
                nested.append(value)
            else:
                ignored.append(str(key))
        elif name not in values:  # first occurrence wins
            values[name] = value
    for sub in nested:
        for key, value in sub.items():
            name = canonical_key(key)
            if name is None:
                ignored.append(str(key))
            elif name not in values:
                values[name] = value
    return values, ignored


def validate_reply(obj: Mapping[str, Any]) -> ParsedReply:
    """Validate one decoded JSON object: coerce, check, clamp (see module docstring)."""
    values, ignored = _flatten(obj)
    missing = [n for n in NUMERIC_FIELDS if n not in values]
    if missing:
        raise ReplyParseError("missing_keys", "missing " + ", ".join(missing))
    numbers: dict[str, float] = {}
    clamped: dict[str, float] = {}
    for name in NUMERIC_FIELDS:
        x = _to_float(name, values[name])
        lo, hi = FIELD_RANGES[name]
        y = min(max(x, lo), hi)
        if y != x:
            clamped[name] = x
        numbers[name] = y
    rationale = _rationale_text(values["rationale"]) if "rationale" in values else ""
    reply = PlannerReply.model_validate({**numbers, "rationale": rationale})
    return ParsedReply(reply=reply, clamped=clamped, ignored_keys=tuple(ignored))


def parse_reply(text: str) -> ParsedReply:
    """Parse raw model text; returns a ``ParsedReply`` or raises ``ReplyParseError``."""
    return validate_reply(extract_json_object(text))


def try_parse_json(text: str) -> dict[str, Any] | None:
    """The reply's JSON object or None (no validation); used for ``LLMResponse.parsed``."""
    try:
        return extract_json_object(text)
    except ReplyParseError:
        return None
