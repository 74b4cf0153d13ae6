"""Robust parsing of model replies into a ``PlannerReply`` (policy tested in ``tests/test_llm_parse.py``).

* ``<think>`` reasoning is removed (a stray ``</think>`` drops what precedes it, an unterminated ``<think>``
  what follows); fences and prose are ignored; a trailing comma is repaired where the text does not decode.
* Of the top-level JSON objects, in text order, the reply is the last complete one (all eight numeric
  fields, possibly one nesting level deep), else the one with the most known fields, else the last:
  models restate an earlier answer before the final one. The choice never looks at values, so an invalid
  last answer makes the reply invalid rather than silently reusing a superseded one.
* Keys: wire keys, long names and variants, case and punctuation insensitive; unknown keys are ignored;
  the last occurrence of a field wins, a direct field over a nested one. Values: numbers or numeric
  strings, finite. A missing numeric field is ``missing_keys``, never filled with a default (it would look
  like the model's choice). Out-of-range values are clamped to ``FIELD_RANGES`` (``ParsedReply.clamped``).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
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


#: A top-level JSON object found in the reply: (start, end) offsets in the scanned text and the object.
_Found = tuple[int, int, dict[str, Any]]


def _scan_objects(text: str) -> list[_Found]:
    """Top-level JSON objects in text order: after an object decodes, scanning resumes at its end."""
    found: list[_Found] = []
    pos = text.find("{")
    while pos >= 0:
        try:
            obj, end = _DECODER.raw_decode(text, pos)
        except (ValueError, RecursionError):
            # JSONDecodeError, over-long ints, absurd nesting: not an object here.
            obj, end = None, pos + 1
        if isinstance(obj, dict):
            found.append((pos, end, obj))
        else:
            end = pos + 1
        pos = text.find("{", end)
    return found


def _scan_with_repair(text: str) -> list[_Found]:
    """``_scan_objects`` plus the objects that decode once trailing commas are removed; a repaired object
    replaces the originals it contains unless it spans exactly one (the regex may have touched a string)."""
    found = _scan_objects(text)
    removed = {m.start() for m in _TRAILING_COMMA_RE.finditer(text)}
    if not removed:
        return found
    kept = [i for i in range(len(text)) if i not in removed]  # repaired index -> original index
    repaired = "".join(text[i] for i in kept)
    merged: list[_Found] = []
    covered: set[int] = set()  # indices into ``found`` inside some repaired object
    for r_start, r_end, obj in _scan_objects(repaired):
        start, end = kept[r_start], kept[r_end - 1] + 1
        inside = [k for k, (s, e, _) in enumerate(found) if start <= s and e <= end]
        covered.update(inside)
        same = [found[k] for k in inside if found[k][:2] == (start, end)]
        merged.append(same[0] if same else (start, end, obj))
    merged.extend(f for k, f in enumerate(found) if k not in covered)
    return sorted(merged, key=lambda f: f[0])


def choose_object(objects: Sequence[Mapping[str, Any]]) -> Mapping[str, Any] | None:
    """The last complete candidate, else the one with the most numeric then known fields (ties: the last),
    else the last object; None if none."""
    if not objects:
        return None
    scored: list[tuple[int, int, Mapping[str, Any]]] = []
    for obj in objects:
        values, _ = _flatten(obj)
        scored.append((sum(1 for name in NUMERIC_FIELDS if name in values), len(values), obj))
    top = max(score[:2] for score in scored)  # (numeric fields, known fields); complete first
    return [obj for n, known, obj in scored if (n, known) == top or n == len(NUMERIC_FIELDS)][-1]


def extract_json_object(text: str) -> dict[str, Any]:
    """The reply's JSON object; raises ``ReplyParseError('no_json')``."""
    if not isinstance(text, str):
        raise ReplyParseError("bad_type", f"reply must be text, got {type(text).__name__}")
    body = strip_reasoning(text[:MAX_REPLY_CHARS])
    chosen = choose_object([obj for _, _, obj in _scan_with_repair(body)])
    if chosen is None:
        raise ReplyParseError("no_json", "no JSON object found in the reply")
    return dict(chosen)


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
    """Canonical name -> raw value, merging one level of nested objects (direct wins, else the last); plus
    ignored keys."""
    direct: dict[str, Any] = {}
    from_nested: dict[str, Any] = {}
    ignored: list[str] = []
    for key, value in obj.items():
        name = canonical_key(key) if isinstance(key, str) else None
        if name is not None:
            direct[name] = value
        elif isinstance(value, dict) and _known_keys(value):
            for sub_key, sub_value in value.items():
                sub_name = canonical_key(sub_key) if isinstance(sub_key, str) else None
                if sub_name is None:
                    ignored.append(str(sub_key))
                else:
                    from_nested[sub_name] = sub_value
        else:
            ignored.append(str(key))
    return {**from_nested, **direct}, ignored


def validate_reply(obj: Mapping[str, Any]) -> ParsedReply:
    """Validate one decoded JSON object: coerce, check, clamp."""
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
