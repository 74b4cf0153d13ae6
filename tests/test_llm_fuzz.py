"""Fuzzing the LLM reply path with hypothesis (issue 15): parser and ParamAdvisor.

Invariants, for every generated reply:

* ``parse_reply`` returns a ``ParsedReply`` or raises ``ReplyParseError`` with a known reason,
  never anything else; every accepted value is finite and inside ``FIELD_RANGES``, and every
  clamp record names a value that was really outside its range;
* ``ParamAdvisor.advise`` over a scripted backend replaying such replies (and transport errors)
  never raises, always returns in-range parameters, and returns exactly the first reply that
  parses (or the fallback when none does);
* when the text holds several complete answers, the last one is used (restated answers).

Example counts per test are in ``N_*``; with test_llm_parse.py's fuzz tests the default suite
parses > 10,000 generated replies (notes/robustness.md).
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Sequence
from typing import Any, TypeVar

import pytest
from fuzz_settings import fuzz
from hypothesis import given
from hypothesis import strategies as st

from letspi.llm.backends.scripted import ScriptedBackend
from letspi.llm.client import ParamAdvisor, RetryPolicy
from letspi.llm.parse import ParsedReply, parse_reply, try_parse_json
from letspi.llm.schema import DEFAULT_REPLY, FIELD_RANGES, NUMERIC_FIELDS, WIRE_KEYS, PlannerReply
from letspi.llm.types import (
    LLMTimeoutError,
    LLMTransportError,
    ReplyParseError,
    RequestFailedError,
    ServerBusyError,
    message,
)
from letspi.physics.params import PARAM_RANGES

N_STRUCTURED = 3000
N_TRUNCATED = 1000  # two replies each (the head and the tail of a cut)
N_RESTATED = 500
N_ADVISOR = 800  # 1-4 script steps each, two thirds of them replies (about 1,300 replies)

T = TypeVar("T")

REASONS = {"no_json", "missing_keys", "bad_value", "non_finite", "bad_type"}
LONG_NAMES = {"tau_s": "tau_s", "k_np": "K_NP", "k_nf": "k-nf", "k_nl": "kLateral", "k_boundary": "k_boundary",
              "k_cline": "k_cline", "lon_factor": "lon_factor", "lane_factor": "Lane Factor"}

# --- strategies ----------------------------------------------------------------------------------

# a character pool rather than st.characters(): ~5x cheaper to draw, and it concentrates on what
# matters here (JSON syntax, whitespace, non-ASCII, zero-width and NUL characters, an emoji)
_CHARS = [*"abcxyz019 .,:;-+eE{}[]\"'\\\n\t<>/", "τ", "é", "ü", "🚗", "\u200b", "\u2028", "\x00", "\ufeff", "≈", "中"]
_unicode = st.text(st.sampled_from(_CHARS), max_size=16)
_PROSE = ["", "Sure! ", "Here is my answer:\n", "```json\n", "\n```", "Answer: ", "I think ", "Note: {not json} ",
          "{", "}", "[1, 2]", "τ = 1.2 s, k_np ≈ 30 🚗 ", "\u200b", "\x00", " Previously: ", "\nRefined:\n"]
_KEYS = [*WIRE_KEYS.values(), *LONG_NAMES.values(), "TAU", "TAU_S", "τ", "k np", "k__np", "lon-factor", "", "x",
         "speed", "params", "goal", "answer", "why", "rationale", "reasoning", "🚗", "\u200bk_np", "k_np\u0000"]


# value *texts* as a model might write them (raw, so NaN/Infinity/duplicates survive)
_VALUE_TEXTS = [
    "0", "-0", "1", "-1", "0.5", "-0.5", "12.5", "30", "99", "-3", "1e2", "1E2", "1e-3", "1e308", "-1e308",
    "1.7976931348623157e308", "5e-324", "1e-400", "1e999", "-1e999", "9" * 30, "9" * 400, "-" + "9" * 400,
    "NaN", "Infinity", "-Infinity", "nan", "inf", "01", "1.", ".5", "+1", "--1", "0x10", "1_000",
    "true", "false", "null", "[]", "[1, 2]", "[30]", "{}", '{"k_np": 3}', '{"tau": NaN}', '"12.5"', '" 3 "',
    '"nan"', '"inf"', '"1e400"', '"abc"', '"12 m/s"', '""', '"τ"', '"-0.5"', '"３"', '"٣.5"', '"1e999"',
    '"\\u0031"', '"🚗"',
]


def _complete_text(values: dict[str, float], rationale: str, long_keys: bool) -> str:
    obj: dict[str, Any] = {("rationale" if long_keys else "why"): rationale}
    for name, value in values.items():
        obj[LONG_NAMES[name] if long_keys else WIRE_KEYS[name]] = value
    return json.dumps(obj, ensure_ascii=False)


class ByteSource:
    """Choices read from a byte string (hypothesis draws the bytes, so it can shrink them).

    Drawing one ``st.binary`` block is far cheaper than hundreds of small draws (about 0.1 ms each
    on a loaded 2-core machine), which is what lets the default suite parse thousands of replies
    in seconds. Exhausted input reads as zeros, which select the simplest options, so shrinking
    the bytes shrinks the reply.
    """

    def __init__(self, data: bytes) -> None:
        self._data = data
        self._pos = 0

    def byte(self) -> int:
        b = self._data[self._pos] if self._pos < len(self._data) else 0
        self._pos += 1
        return b

    def below(self, n: int) -> int:
        return (self.byte() | self.byte() << 8) % n

    def choice(self, options: Sequence[T]) -> T:
        return options[self.below(len(options))]

    def chance(self, per_256: int) -> bool:
        return self.byte() < per_256

    def text(self, max_len: int = 16) -> str:
        return "".join(self.choice(_CHARS) for _ in range(self.below(max_len + 1)))

    def double(self) -> float:
        return float(struct.unpack("<d", bytes(self.byte() for _ in range(8)))[0])


def _number_text(x: float) -> str:
    if math.isnan(x):
        return "NaN"
    if math.isinf(x):
        return "Infinity" if x > 0 else "-Infinity"
    return repr(x)


def _value_from(src: ByteSource, name: str | None) -> str:
    kind = src.below(8)
    if name is not None and name != "rationale" and kind < 4:  # in range (also both bounds)
        lo, hi = FIELD_RANGES[name]
        return repr(round(lo + (hi - lo) * src.byte() / 255, 6))
    if name == "rationale" and kind < 5:
        return json.dumps(src.text(30), ensure_ascii=src.chance(128))
    if kind == 4:
        return _number_text(src.double())  # any double, NaN and infinities included
    if kind == 5:
        return str(src.below(2**16) * 10 ** src.below(45) * src.choice([1, -1]))  # huge integers
    if kind == 6:
        return json.dumps(src.text())  # a string (maybe with unicode, braces, NUL)
    return src.choice(_VALUE_TEXTS)


def object_from(src: ByteSource, depth: int = 0) -> str:
    """One JSON-ish object: reply keys (wire or long names, duplicates possible), odd values, unknown
    keys, maybe a nested object, maybe damaged (trailing comma, single quotes, unclosed, unquoted)."""
    pairs: list[tuple[str, str]] = []
    for _ in range(src.below(12)):
        if src.chance(200):
            name = src.choice([*NUMERIC_FIELDS, "rationale"])
            key = WIRE_KEYS[name] if src.chance(180) else LONG_NAMES.get(name, "reasoning")
            pairs.append((key, _value_from(src, name)))
        else:
            pairs.append((src.choice(_KEYS), _value_from(src, None)))
    if depth < 2 and src.chance(60):
        nested = (src.choice(["params", "goal", "answer", "x"]), object_from(src, depth + 1))
        pairs.insert(src.below(len(pairs) + 1), nested)
    body = "{" + ", ".join(f"{json.dumps(k, ensure_ascii=False)}: {v}" for k, v in pairs) + "}"
    damage = src.below(16)
    if damage == 1:
        body = body[:-1] + ",}"
    elif damage == 2:
        body = body.replace('"', "'")
    elif damage == 3:
        body = body[:-1]
    elif damage == 4:
        body = body.replace('"', "")
    elif damage == 5:
        body = body[: src.below(len(body) + 1)]
    return body


def complete_from(src: ByteSource) -> str:
    values = {}
    for name in NUMERIC_FIELDS:
        lo, hi = FIELD_RANGES[name]
        values[name] = round(lo + (hi - lo) * src.byte() / 255, 4)
    return _complete_text(values, src.text(), src.chance(100))


def reply_from(data: bytes) -> str:
    """A whole reply: prose, <think> blocks (closed, open, stray), fences, objects, complete answers."""
    src = ByteSource(data)
    parts: list[str] = []
    for _ in range(1 + src.below(6)):
        kind = src.below(9)
        if kind == 0:
            parts.append(complete_from(src))
        elif kind in (1, 2):
            parts.append(object_from(src))
        elif kind == 3:
            parts.append(src.choice(_PROSE) if src.chance(128) else src.text(40))
        elif kind == 4:
            parts.append("<think>" + (object_from(src) if src.chance(128) else src.text(40)) + "</think>")
        elif kind == 5:
            parts.append(src.choice(["<think>", "<THINK>", "</think>", "</Think>"]))
        elif kind == 6:
            parts.append("```json\n" + object_from(src) + "\n```")
        elif kind == 7:
            parts.append(complete_from(src) + src.choice(_PROSE) + complete_from(src))  # restated answer
        else:
            parts.append(json.dumps(src.choice([[1, 2], "text", 3.5, None, [{"k_np": 1}]])))
    return src.choice(["", " ", "\n"]).join(parts)


def check(text: str) -> ParsedReply | None:
    """The invariants; returns the parsed reply (None for a typed rejection)."""
    try:
        parsed = parse_reply(text)
    except ReplyParseError as exc:
        assert exc.reason in REASONS, exc
        assert try_parse_json(text) is None or exc.reason != "no_json"
        return None
    assert isinstance(parsed, ParsedReply) and isinstance(parsed.reply, PlannerReply)
    for name in NUMERIC_FIELDS:
        value = getattr(parsed.reply, name)
        lo, hi = FIELD_RANGES[name]
        assert isinstance(value, float) and math.isfinite(value) and lo <= value <= hi, (name, value)
    for name, given_value in parsed.clamped.items():
        lo, hi = FIELD_RANGES[name]
        assert math.isfinite(given_value) and not lo <= given_value <= hi, (name, given_value)
        assert getattr(parsed.reply, name) == min(max(given_value, lo), hi)
    for name, (lo, hi) in PARAM_RANGES.items():  # what the physics accepts
        if name in parsed.reply.params():
            assert lo <= parsed.reply.params()[name] <= hi
    assert isinstance(parsed.reply.rationale, str) and len(parsed.reply.rationale) <= 2000
    assert try_parse_json(text) is not None
    return parsed


# --- parser ----------------------------------------------------------------------------------------


_bytes = st.binary(max_size=600)


@fuzz(N_STRUCTURED)
@given(_bytes)
def test_fuzz_structured_replies(data: bytes) -> None:
    check(reply_from(data))


@fuzz(N_TRUNCATED)
@given(_bytes, st.integers(0, 10**6))
def test_fuzz_truncated_replies(data: bytes, cut: int) -> None:
    text = reply_from(data)
    cut %= len(text) + 1
    check(text[:cut])  # a reply cut off (max_tokens, dropped connection)
    check(text[cut:])  # and one that starts in the middle


@fuzz(N_RESTATED)
@given(_bytes)
def test_fuzz_restated_answers_use_the_last_complete_one(data: bytes) -> None:
    src = ByteSource(data)

    def prose() -> str:  # no "{" (no accidental objects) and no "<" (no think tags)
        return "".join(c for c in src.text(20) if c not in "{<")

    answers = []
    pieces = []
    for _ in range(2 + src.below(3)):
        values = {name: round(lo + (hi - lo) * src.byte() / 255, 4) for name, (lo, hi) in FIELD_RANGES.items()}
        answers.append(values)
        pieces += [prose(), _complete_text(values, prose(), src.chance(100))]
    # a partial object after the final answer ("note that {"k_np": 99} would be too much") must not win
    if src.chance(128):
        pieces.append(prose() + json.dumps({"k_np": 99}))
    pieces.append(prose())
    parsed = check("".join(pieces))
    assert parsed is not None
    assert {name: getattr(parsed.reply, name) for name in NUMERIC_FIELDS} == answers[-1]
    assert parsed.clamped == {}


# --- the advisor -----------------------------------------------------------------------------------

_failure = st.sampled_from(
    [
        LLMTransportError("HTTP 500", status=500),
        LLMTimeoutError("no reply within 5 s"),
        ServerBusyError("HTTP 429", status=429, retry_after_s=1.0),
        ServerBusyError("HTTP 503", status=503, retry_after_s=None),
    ]
)


@fuzz(N_ADVISOR)
@given(st.lists(st.one_of(_bytes, _bytes, _failure), min_size=1, max_size=4))
def test_fuzz_advisor_never_crashes_and_uses_the_first_valid_reply(
    script: list[bytes | LLMTransportError],
) -> None:
    steps = [reply_from(s) if isinstance(s, bytes) else s for s in script]
    sleeps: list[float] = []
    advisor = ParamAdvisor(
        ScriptedBackend(steps),
        cache=None,
        retry=RetryPolicy(max_attempts=len(steps), jitter=0.0),
        sleep=sleeps.append,
    )
    expected = None
    for step in steps:
        if isinstance(step, str):
            try:
                expected = parse_reply(step)
                break
            except ReplyParseError:
                continue
    if expected is None and any(not isinstance(step, str) for step in steps):
        # no valid reply and an attempt lost in transport: not a fallback, the request failed
        with pytest.raises(RequestFailedError):
            advisor.advise([message("system", "s"), message("user", "u")])
        return
    advice = advisor.advise([message("system", "s"), message("user", "u")])
    if expected is None:
        assert advice.fallback and advice.reply == DEFAULT_REPLY
        assert len(advice.attempts) == len(steps)
    else:
        assert not advice.fallback and advice.reply == expected.reply and advice.clamped == expected.clamped
    for name in NUMERIC_FIELDS:
        lo, hi = FIELD_RANGES[name]
        value = getattr(advice.reply, name)
        assert math.isfinite(value) and lo <= value <= hi
    assert all(s >= 0 for s in sleeps)
