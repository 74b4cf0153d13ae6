"""ParamAdvisor control flow against the scripted backend (no model, no network)."""

from __future__ import annotations

import json
import pickle
import random
from pathlib import Path

import pytest

from letspi.llm.backends.scripted import ScriptedBackend, ScriptedStep
from letspi.llm.cache import ResponseCache
from letspi.llm.client import ParamAdvisor, RetryPolicy
from letspi.llm.schema import DEFAULT_REPLY
from letspi.llm.types import (
    BackendUnavailableError,
    LLMTimeoutError,
    LLMTransportError,
    Message,
    ModelNotFoundError,
    RequestFailedError,
    RequestRejectedError,
    ServerBusyError,
    message,
)

GOOD = {"why": "ok", "tau": 1.1, "k_np": 20, "k_nf": 3, "k_nl": 1, "k_bd": 1, "k_cl": 0.5, "lon": 0.5, "lane": 0}
MSGS: list[Message] = [message("system", "static"), message("user", "scenario")]


def advisor(
    backend: ScriptedBackend, *, attempts: int = 3, cache: ResponseCache | None = None
) -> tuple[ParamAdvisor, list[float]]:
    sleeps: list[float] = []
    adv = ParamAdvisor(
        backend,
        cache=cache,
        retry=RetryPolicy(max_attempts=attempts, backoff_s=0.5, timeout_s=5.0, jitter=0.0),
        sleep=sleeps.append,
    )
    return adv, sleeps


def test_good_reply_first_try() -> None:
    be = ScriptedBackend([json.dumps(GOOD)])
    adv, sleeps = advisor(be)
    a = adv.advise(MSGS)
    assert not a.fallback and a.reply.k_np == 20 and len(a.attempts) == 1 and sleeps == []
    assert be.schemas[0] is not None and "why" in be.schemas[0]["properties"]
    assert a.summary()["errors"] == []


def test_fast_variant_sends_fast_schema() -> None:
    be = ScriptedBackend([json.dumps({k: v for k, v in GOOD.items() if k != "why"})])
    adv, _ = advisor(be)
    a = adv.advise(MSGS, variant="fast")
    assert not a.fallback and be.schemas[0] is not None and "why" not in be.schemas[0]["properties"]


def test_malformed_then_good_retries_with_correction() -> None:
    be = ScriptedBackend(['{"tau": 1.0, "k_np": ', json.dumps(GOOD)])
    adv, sleeps = advisor(be)
    a = adv.advise(MSGS)
    assert not a.fallback and [x.error_kind for x in a.attempts] == ["parse:no_json", None]
    assert sleeps == []  # invalid replies are re-asked at once
    retry_msgs = be.calls[1]
    assert retry_msgs[:2] == MSGS and retry_msgs[2]["role"] == "assistant"
    assert retry_msgs[3]["role"] == "user" and "not valid" in retry_msgs[3]["content"]


def test_out_of_range_clamped_and_recorded() -> None:
    be = ScriptedBackend([json.dumps({**GOOD, "k_np": 500, "lon": -1})])
    a = advisor(be)[0].advise(MSGS)
    assert not a.fallback and a.reply.k_np == 60 and a.reply.lon_factor == 0
    assert a.clamped == {"k_np": 500.0, "lon_factor": -1.0}


@pytest.mark.parametrize(
    "bad, reason",
    [
        (json.dumps(GOOD).replace('"k_np": 20', '"k_np": NaN'), "parse:non_finite"),
        (json.dumps({k: v for k, v in GOOD.items() if k != "k_nl"}), "parse:missing_keys"),
        ("I would pick tau=1 and k_np=20.", "parse:no_json"),
    ],
)
def test_invalid_then_good(bad: str, reason: str) -> None:
    be = ScriptedBackend([bad, json.dumps(GOOD)])
    a = advisor(be)[0].advise(MSGS)
    assert not a.fallback and a.attempts[0].error_kind == reason


def test_extra_keys_prose_and_think() -> None:
    text = "<think>the leader is close</think>Answer:\n```json\n" + json.dumps({**GOOD, "comment": "x"}) + "\n```"
    a = advisor(ScriptedBackend([text]))[0].advise(MSGS)
    assert not a.fallback and a.reply.tau_s == 1.1


def test_http_500_then_success_backs_off() -> None:
    be = ScriptedBackend([LLMTransportError("HTTP 500"), LLMTransportError("HTTP 502"), json.dumps(GOOD)])
    a, sleeps = (lambda adv_s: (adv_s[0].advise(MSGS), adv_s[1]))(advisor(be))
    assert not a.fallback and [x.error_kind for x in a.attempts] == ["transport", "transport", None]
    assert sleeps == [0.5, 1.0]  # exponential backoff
    assert be.calls[0] == be.calls[1] == be.calls[2] == MSGS  # transport retries resend as is


def test_timeout_then_success() -> None:
    be = ScriptedBackend([ScriptedStep(text=json.dumps(GOOD), latency_s=60.0), json.dumps(GOOD)])
    a = advisor(be)[0].advise(MSGS)
    assert not a.fallback and a.attempts[0].error_kind == "timeout"


def test_all_attempts_bad_falls_back() -> None:
    be = ScriptedBackend(["nope", "still prose", '{"tau": "fast"}'])
    a = advisor(be)[0].advise(MSGS)
    assert a.fallback and a.reply == DEFAULT_REPLY and len(a.attempts) == 3
    assert [x.error_kind for x in a.attempts] == ["parse:no_json", "parse:no_json", "parse:missing_keys"]
    assert a.summary()["fallback"] is True and be.remaining == 0


def test_a_transport_failure_among_the_attempts_is_not_a_fallback() -> None:
    """A fallback means the model had every attempt; one lost in transport makes the request fail
    (the scenario is not stored, a rerun retries it)."""
    be = ScriptedBackend(["nope", LLMTransportError("HTTP 500"), '{"tau": "fast"}'])
    with pytest.raises(RequestFailedError, match=r"no valid reply in 3 attempts \(parse:no_json, transport, "
                                                 r"parse:missing_keys\).*HTTP 500"):
        advisor(be)[0].advise(MSGS)
    assert be.remaining == 0


def test_a_rejected_request_falls_back_at_once() -> None:
    be = ScriptedBackend([RequestRejectedError("HTTP 400: prompt too long", status=400), json.dumps(GOOD)])
    adv, sleeps = advisor(be)
    a = adv.advise(MSGS)
    assert a.fallback and [x.error_kind for x in a.attempts] == ["rejected"] and be.remaining == 1 and sleeps == []
    assert adv.breaker.consecutive_failures == 0


def test_configured_attempt_count() -> None:
    be = ScriptedBackend(["bad"] * 5)
    a = advisor(be, attempts=5)[0].advise(MSGS)
    assert a.fallback and len(a.attempts) == 5 and be.remaining == 0
    with pytest.raises(ValueError):
        RetryPolicy(max_attempts=0)


def test_config_errors_raise_immediately() -> None:
    be = ScriptedBackend([ModelNotFoundError("run `ollama pull x`"), json.dumps(GOOD)])
    with pytest.raises(ModelNotFoundError):
        advisor(be)[0].advise(MSGS)
    assert be.remaining == 1


def test_unreachable_on_every_attempt_raises_but_a_blip_does_not() -> None:
    with pytest.raises(BackendUnavailableError):
        advisor(ScriptedBackend([BackendUnavailableError("ollama serve")] * 3))[0].advise(MSGS)
    be = ScriptedBackend([BackendUnavailableError("down"), json.dumps(GOOD)])
    assert not advisor(be)[0].advise(MSGS).fallback


def test_cache_makes_rerun_free_and_identical(tmp_path: Path) -> None:
    cache = ResponseCache(tmp_path / "c.sqlite")
    be = ScriptedBackend(["garbage", json.dumps(GOOD)])
    first = advisor(be, cache=cache)[0].advise(MSGS)
    assert not first.cached and len(cache) == 2  # the bad reply is cached too: replayable
    be2 = ScriptedBackend([])  # would fail if called
    second = advisor(be2, cache=cache)[0].advise(MSGS)
    assert second.cached and second.reply == first.reply and be2.calls == []
    assert [x.error_kind for x in second.attempts] == ["parse:no_json", None]


def test_default_cache_location_env(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("LETSPI_CACHE_DIR", str(tmp_path / "cachedir"))
    adv = ParamAdvisor(ScriptedBackend([json.dumps(GOOD)]))
    assert adv.cache is not None and adv.cache.path == tmp_path / "cachedir" / "llm_cache.sqlite"
    adv.advise(MSGS)
    assert len(adv.cache) == 1
    assert ParamAdvisor(ScriptedBackend([]), cache=None).cache is None


def test_spec_string_backend() -> None:
    a = ParamAdvisor("scripted:default", cache=None).advise(MSGS)
    assert not a.fallback and a.reply.params() == DEFAULT_REPLY.params()


def test_backoff_has_jitter_within_bounds() -> None:
    seen: set[tuple[float, ...]] = set()
    for seed in range(5):
        sleeps: list[float] = []
        be = ScriptedBackend([LLMTransportError("HTTP 500")] * 3 + [json.dumps(GOOD)])
        adv = ParamAdvisor(
            be, cache=None, retry=RetryPolicy(max_attempts=4, backoff_s=0.5, jitter=0.5),
            sleep=sleeps.append, rng=random.Random(seed),
        )
        assert not adv.advise(MSGS).fallback
        assert len(sleeps) == 3
        for s, full in zip(sleeps, (0.5, 1.0, 2.0), strict=True):
            assert full * 0.5 <= s <= full  # equal jitter: half fixed, half random
        seen.add(tuple(sleeps))
    assert len(seen) == 5  # different draws: clients do not retry in lockstep


def test_retry_after_is_a_floor_for_that_request() -> None:
    be = ScriptedBackend(
        [
            ServerBusyError("HTTP 429", status=429, retry_after_s=3.0),  # server wait > backoff
            ServerBusyError("HTTP 503", status=503, retry_after_s=0.1),  # backoff > server wait
            json.dumps(GOOD),
        ]
    )
    adv, sleeps = advisor(be, attempts=3)
    a = adv.advise(MSGS)
    assert not a.fallback and [x.error_kind for x in a.attempts] == ["busy", "busy", None]
    assert sleeps == [3.0, 1.0]  # max(backoff 0.5, 3.0), then max(backoff 1.0, 0.1)
    assert RetryPolicy(jitter=0.0).wait_s(1, 2.5) == 2.5 and RetryPolicy(jitter=0.0).wait_s(1, None) == 0.5


def test_retry_after_longer_than_the_policy_stops_instead_of_falling_back() -> None:
    be = ScriptedBackend([ServerBusyError("HTTP 429: quota", status=429, retry_after_s=3600.0), json.dumps(GOOD)])
    adv, sleeps = advisor(be)
    with pytest.raises(ServerBusyError) as e:
        adv.advise(MSGS)
    assert "3600 s" in str(e.value) and "120 s" in str(e.value) and e.value.retry_after_s == 3600.0
    assert sleeps == [] and be.remaining == 1


def test_transport_errors_keep_status_and_retry_after_when_pickled() -> None:
    for err in (
        ServerBusyError("busy", status=503, retry_after_s=2.0),
        LLMTransportError("HTTP 500", status=500),
        LLMTimeoutError("slow"),
        BackendUnavailableError("down"),
    ):
        back = pickle.loads(pickle.dumps(err))
        assert type(back) is type(err) and str(back) == str(err)
        assert (back.status, back.retry_after_s) == (err.status, err.retry_after_s)


def test_retry_policy_validation() -> None:
    for bad in ({"jitter": 1.5}, {"jitter": -0.1}, {"max_retry_after_s": -1.0}, {"backoff_s": -1.0}):
        with pytest.raises(ValueError):
            RetryPolicy(**bad)  # type: ignore[arg-type]


OPTIONS = {"default": DEFAULT_REPLY, "keep-gap": DEFAULT_REPLY.model_copy(update={"k_np": 40.0, "lon_factor": 0.7})}


def test_choose_returns_the_named_option_and_constrains_the_reply_to_the_names() -> None:
    be = ScriptedBackend(['{"option": "keep-gap"}'])
    adv, _ = advisor(be)
    a = adv.choose(MSGS, OPTIONS)
    assert a.choice == "keep-gap" and not a.fallback and a.reply.k_np == 40.0 and a.reply.lon_factor == 0.7
    assert be.schemas[0] is not None and be.schemas[0]["properties"]["option"]["enum"] == ["default", "keep-gap"]
    assert a.summary()["choice"] == "keep-gap"


def test_choose_re_asks_after_an_unknown_name_and_falls_back_to_the_first_option() -> None:
    be = ScriptedBackend(['{"option": "brake"}', '{"option": "keep-gap"}'])
    adv, _ = advisor(be)
    a = adv.choose(MSGS, OPTIONS)
    assert a.choice == "keep-gap" and [x.error_kind for x in a.attempts] == ["parse:bad_value", None]
    assert "one of: default, keep-gap" in be.calls[1][-1]["content"]  # the corrective message names them
    be = ScriptedBackend(["no json", '{"o": 1}'])
    adv, _ = advisor(be, attempts=2)
    a = adv.choose(MSGS, OPTIONS)
    assert a.fallback and a.choice == "default" and a.reply == DEFAULT_REPLY
    with pytest.raises(ValueError, match="at least one option"):
        adv.choose(MSGS, {})
