"""Reply parser: policy cases and hypothesis fuzzing (returns a result or a typed error)."""

from __future__ import annotations

import json
import math

import pytest
from fuzz_settings import fuzz
from hypothesis import given
from hypothesis import strategies as st

from letspi.llm.parse import ParsedReply, extract_json_object, parse_reply, strip_reasoning
from letspi.llm.schema import FIELD_RANGES, NUMERIC_FIELDS, WIRE_KEYS, PlannerReply, reply_json_schema
from letspi.llm.types import ReplyParseError

GOOD = {
    "why": "leader close",
    "tau": 1.2,
    "k_np": 30,
    "k_nf": 4,
    "k_nl": 1.5,
    "k_bd": 1,
    "k_cl": 0.5,
    "lon": 0.7,
    "lane": 0,
}


def dumps(obj: dict) -> str:
    return json.dumps(obj)


def test_plain_json() -> None:
    r = parse_reply(dumps(GOOD))
    assert r.reply.k_np == 30 and r.reply.tau_s == 1.2 and r.reply.rationale == "leader close"
    assert r.clamped == {} and r.ignored_keys == ()


def test_prose_and_code_fence_around_json() -> None:
    text = "Sure! Here are the parameters:\n```json\n" + json.dumps(GOOD, indent=2) + "\n```\nHope it helps {not json}."
    assert parse_reply(text).reply.lon_factor == 0.7


def test_think_blocks() -> None:
    decoy = json.dumps({**GOOD, "k_np": 1})
    assert parse_reply(f"<think>maybe {decoy}</think>\n{dumps(GOOD)}").reply.k_np == 30
    # stray closing tag (template opened the block): everything before it is reasoning
    assert parse_reply(f"thinking {decoy} </think> {dumps(GOOD)}").reply.k_np == 30
    # unterminated: the unfinished reasoning is dropped, so only a JSON before it counts
    assert parse_reply(f"{dumps(GOOD)} <think> and then {decoy}").reply.k_np == 30
    with pytest.raises(ReplyParseError) as e:
        parse_reply(f"<think> let me see {dumps(GOOD)}")
    assert e.value.reason == "no_json"
    assert strip_reasoning("a<THINK>x</THINK>b") == "ab"


def test_numbers_as_strings_and_long_names() -> None:
    obj = {
        "rationale": "x",
        "tau_s": "1.5",
        "K_NP": " 12 ",
        "k-nf": 3,
        "k_nl": "2e0",
        "k_boundary": 1,
        "k_cline": ".5",
        "lon_factor": "0.3",
        "lane_factor": "-0.5",
    }
    r = parse_reply(dumps(obj))
    assert (r.reply.tau_s, r.reply.k_np, r.reply.k_nl, r.reply.k_cline, r.reply.lane_factor) == (1.5, 12, 2, 0.5, -0.5)


def test_out_of_range_is_clamped_and_recorded() -> None:
    r = parse_reply(dumps({**GOOD, "k_np": 99, "tau": 0.0, "lane": -3}))
    assert r.reply.k_np == 60 and r.reply.tau_s == 0.3 and r.reply.lane_factor == -1
    assert r.clamped == {"k_np": 99.0, "tau_s": 0.0, "lane_factor": -3.0}


@pytest.mark.parametrize("bad", ["NaN", "Infinity", "-Infinity"])
def test_nan_and_inf_rejected(bad: str) -> None:
    text = dumps(GOOD).replace('"k_np": 30', f'"k_np": {bad}')
    with pytest.raises(ReplyParseError) as e:
        parse_reply(text)
    assert e.value.reason == "non_finite"


@pytest.mark.parametrize("value", ["nan", "inf", "12 m/s", True, None, [1], {"a": 1}])
def test_bad_values_rejected(value: object) -> None:
    with pytest.raises(ReplyParseError) as e:
        parse_reply(dumps({**GOOD, "k_np": value}))
    assert e.value.reason in ("bad_value", "non_finite")


def test_huge_numbers() -> None:
    with pytest.raises(ReplyParseError):
        parse_reply(dumps(GOOD).replace('"k_np": 30', '"k_np": 1e999'))
    with pytest.raises(ReplyParseError) as e:  # an int too big for a float is not a usable number
        parse_reply(dumps(GOOD).replace('"k_np": 30', '"k_np": ' + "9" * 400))
    assert e.value.reason == "non_finite"
    r = parse_reply(dumps(GOOD).replace('"k_np": 30', '"k_np": ' + "9" * 30))  # big but finite: clamped
    assert r.reply.k_np == 60 and "k_np" in r.clamped


def test_missing_keys_invalid_extra_keys_ignored() -> None:
    partial = {k: v for k, v in GOOD.items() if k not in ("k_nf", "lane")}
    with pytest.raises(ReplyParseError) as e:
        parse_reply(dumps(partial))
    assert e.value.reason == "missing_keys" and "k_nf" in e.value.detail and "lane_factor" in e.value.detail
    r = parse_reply(dumps({**GOOD, "speed": 3, "notes": "x"}))
    assert set(r.ignored_keys) == {"speed", "notes"}
    # rationale is optional
    assert parse_reply(dumps({k: v for k, v in GOOD.items() if k != "why"})).reply.rationale == ""


def test_nested_objects_merged() -> None:
    text = dumps(
        {
            "params": {k: GOOD[k] for k in ("tau", "k_np", "k_nf", "k_nl", "k_bd", "k_cl")},
            "goal": {"lon": 0.2, "lane": 1},
            "why": "w",
        }
    )
    r = parse_reply(text)
    assert r.reply.lon_factor == 0.2 and r.reply.lane_factor == 1 and r.reply.k_np == 30


def test_last_complete_object_wins_and_trailing_comma_repair() -> None:
    text = 'Format: {"example": 1}. Answer: ' + dumps(GOOD) + " or " + dumps({**GOOD, "k_np": 2})
    assert parse_reply(text).reply.k_np == 2
    assert parse_reply(dumps(GOOD)[:-1] + ",}").reply.k_np == 30


def test_restated_old_answer_before_the_new_one() -> None:
    old = {**GOOD, "k_np": 12, "why": "previous"}
    new = {**GOOD, "k_np": 45, "lon": 0.9, "why": "refined"}
    for text in (
        f"My previous answer was {dumps(old)}. The refined answer is:\n{dumps(new)}",
        f"```json\n{dumps(old)}\n```\nUpdated:\n```json\n{dumps(new)}\n```",
        f"<think>{dumps(new)}</think>Before: {dumps(old)} After: {dumps(new)} (done)",
    ):
        r = parse_reply(text).reply
        assert (r.k_np, r.lon_factor, r.rationale) == (45, 0.9, "refined")


def test_a_later_partial_object_does_not_replace_a_complete_answer() -> None:
    text = f"{dumps(GOOD)}\nNote that {dumps({'k_np': 99})} would be too aggressive."
    assert parse_reply(text).reply.k_np == 30
    # with no complete object, the most complete one is reported as missing keys
    with pytest.raises(ReplyParseError) as e:
        parse_reply('{"k_np": 1} and {"tau": 1, "k_np": 2, "k_nf": 3}')
    assert e.value.reason == "missing_keys" and "tau_s" not in e.value.detail and "k_nl" in e.value.detail


def test_a_last_complete_but_invalid_answer_is_not_replaced_by_an_earlier_one() -> None:
    text = dumps(GOOD) + " then " + dumps(GOOD).replace('"k_np": 30', '"k_np": NaN')
    with pytest.raises(ReplyParseError) as e:
        parse_reply(text)
    assert e.value.reason == "non_finite"


def test_trailing_comma_in_the_last_answer_only() -> None:
    text = dumps({**GOOD, "k_np": 12}) + " now: " + dumps({**GOOD, "k_np": 44})[:-1] + ",}"
    assert parse_reply(text).reply.k_np == 44
    # a repair never touches an object that decodes as is (the comma here is inside a string)
    text = dumps({**GOOD, "why": "gap, ]"})
    assert parse_reply(text).reply.rationale == "gap, ]"


def test_nested_objects_are_part_of_their_outer_object() -> None:
    # the inner objects are not candidates of their own: the merged outer object is the answer
    text = dumps({"params": {k: GOOD[k] for k in ("tau", "k_np", "k_nf", "k_nl", "k_bd", "k_cl")},
                  "goal": {"lon": 0.1, "lane": 1}})
    r = parse_reply(text).reply
    assert (r.k_np, r.lon_factor, r.lane_factor) == (30, 0.1, 1)


def test_duplicate_keys_take_the_last_value() -> None:
    text = dumps(GOOD)[:-1] + ', "k_np": 7}'
    assert parse_reply(text).reply.k_np == 7
    assert parse_reply(dumps({**GOOD, "k_np": 5, "K-NP": 8})).reply.k_np == 8


def test_no_json_and_non_object() -> None:
    for text in ["", "no braces here", "[1, 2, 3]", "{broken", "{'tau': 1}"]:
        with pytest.raises(ReplyParseError):
            parse_reply(text)
    with pytest.raises(ReplyParseError) as e:
        extract_json_object(123)  # type: ignore[arg-type]
    assert e.value.reason == "bad_type"


def test_wire_round_trip_and_schema() -> None:
    reply = PlannerReply(
        tau_s=1, k_np=2, k_nf=3, k_nl=4, k_boundary=1, k_cline=0.5, lon_factor=0.1, lane_factor=-0.2, rationale="r"
    )
    assert parse_reply(dumps(reply.to_wire("physics"))).reply == reply
    fast = reply.to_wire("fast")
    assert "why" not in fast
    schema = reply_json_schema("physics")
    assert next(iter(schema["properties"])) == "why"
    assert set(schema["required"]) == set(WIRE_KEYS.values())
    assert "why" not in reply_json_schema("fast")["properties"]


# --- fuzzing -----------------------------------------------------------------------------

_keys = st.sampled_from([*WIRE_KEYS.values(), "tau_s", "k_boundary", "lon_factor", "x", "τ", "", "K NP"])
_values = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.text(max_size=12),
    st.sampled_from(["1.5", " 3 ", "nan", "-inf", "1e400", ".5", "5.", "+2", "--1"]),
    st.booleans(),
    st.none(),
    st.lists(st.integers(), max_size=2),
)
_json_objects = st.dictionaries(_keys, _values, max_size=12)


def _check(text: str) -> None:
    try:
        r = parse_reply(text)
    except ReplyParseError as exc:
        assert exc.reason in {"no_json", "missing_keys", "bad_value", "non_finite", "bad_type"}
        return
    assert isinstance(r, ParsedReply)
    for name in NUMERIC_FIELDS:
        v = getattr(r.reply, name)
        lo, hi = FIELD_RANGES[name]
        assert math.isfinite(v) and lo <= v <= hi


@fuzz(1500)
@given(st.text(max_size=300))
def test_fuzz_random_text(text: str) -> None:
    _check(text)


@fuzz(1500)
@given(
    _json_objects, st.text(max_size=30), st.text(max_size=30), st.sampled_from(["", "<think>", "</think>", "```json\n"])
)
def test_fuzz_json_objects_with_noise(obj: dict, before: str, after: str, tag: str) -> None:
    try:
        body = json.dumps(obj, allow_nan=True)
    except (TypeError, ValueError):
        return
    _check(before + tag + body + after)


@fuzz(1500)
@given(st.data())
def test_fuzz_mutated_good_replies(data: st.DataObject) -> None:
    text = dumps(GOOD)
    n_mut = data.draw(st.integers(min_value=1, max_value=6))
    chars = list(text)
    for _ in range(n_mut):
        op = data.draw(st.sampled_from(["del", "ins", "swap"]))
        i = data.draw(st.integers(min_value=0, max_value=max(len(chars) - 1, 0)))
        if op == "del" and chars:
            del chars[i]
        elif op == "ins":
            chars.insert(i, data.draw(st.sampled_from([*'{}[]",:.-0123456789eE aN', "NaN", "<think>"])))
        elif chars:
            chars[i] = data.draw(st.characters())
    _check("".join(chars))
