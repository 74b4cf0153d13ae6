"""Ollama and OpenAI-compatible clients against tiny real HTTP servers speaking their wire formats."""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Callable, Iterator
from email.utils import formatdate
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import pytest

from letspi.llm.backends._http import parse_retry_after
from letspi.llm.backends.ollama import OllamaBackend
from letspi.llm.backends.openai_compat import DEMOTE_AFTER_NO_JSON, OpenAICompatBackend
from letspi.llm.client import ParamAdvisor, RetryPolicy
from letspi.llm.schema import reply_json_schema
from letspi.llm.types import (
    BackendUnavailableError,
    DecodingSettings,
    LLMConfigError,
    LLMTimeoutError,
    LLMTransportError,
    ModelNotFoundError,
    RequestFailedError,
    ServerBusyError,
    message,
)

GOOD = {"why": "ok", "tau": 1.1, "k_np": 20, "k_nf": 3, "k_nl": 1, "k_bd": 1, "k_cl": 0.5, "lon": 0.5, "lane": 0}
MSGS = [message("system", "static"), message("user", "scenario")]
Route = Callable[[str, dict[str, Any], int], tuple[Any, ...]]


class FakeServer:
    """A ThreadingHTTPServer on 127.0.0.1 whose POST handler is
    ``route(path, body, n) -> (status, json)`` or ``(status, json, headers)``.
    ``arrivals`` holds the ``time.monotonic()`` of each request's arrival."""

    def __init__(self, route: Route) -> None:
        self.requests: list[tuple[str, dict[str, Any]]] = []
        self.arrivals: list[float] = []
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:
                outer.arrivals.append(time.monotonic())
                body = json.loads(self.rfile.read(int(self.headers.get("Content-Length", 0))) or b"{}")
                outer.requests.append((self.path, body))
                status, payload, *rest = route(self.path, body, len(outer.requests))
                data = json.dumps(payload).encode()
                self.send_response(status)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(data)))
                for key, value in (rest[0] if rest else {}).items():
                    self.send_header(key, value)
                self.end_headers()
                self.wfile.write(data)

            def log_message(self, *args: Any) -> None:
                pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
        self.thread.start()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.httpd.server_address[1]}"

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture
def serve() -> Iterator[Callable[[Route], FakeServer]]:
    servers: list[FakeServer] = []

    def start(route: Route) -> FakeServer:
        servers.append(FakeServer(route))
        return servers[-1]

    yield start
    for s in servers:
        s.close()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


# --- Ollama ------------------------------------------------------------------------------------


def ollama_route(path: str, body: dict[str, Any], n: int) -> tuple[int, Any]:
    assert path == "/api/chat"
    model = body["model"]
    if model == "missing":
        return 404, {"error": f'model "{model}" not found, try pulling it first'}
    if model == "flaky" and n == 1:
        return 500, {"error": "llama runner process has terminated"}
    if model == "slow":
        time.sleep(1.0)
    if model == "thinker":
        content = "<think>leader is close, raise k_np</think>" + json.dumps(GOOD)
    else:
        content = json.dumps(GOOD)
    return 200, {
        "model": model,
        "created_at": "2025-01-01T00:00:00Z",
        "message": {"role": "assistant", "content": content},
        "done": True,
        "done_reason": "stop",
        "total_duration": 1_000_000,
        "prompt_eval_count": 42,
        "eval_count": 17,
    }


def test_ollama_request_and_reply(serve: Callable[[Route], FakeServer]) -> None:
    srv = serve(ollama_route)
    be = OllamaBackend("llama3.1:8b", base_url=srv.url)
    schema = reply_json_schema("physics")
    r = be.complete(MSGS, schema=schema, settings=DecodingSettings(seed=7, max_tokens=99), timeout_s=5)
    assert (
        r.parsed == GOOD
        and r.prompt_tokens == 42
        and r.completion_tokens == 17
        and r.model_spec == "ollama:llama3.1:8b"
    )
    _path, body = srv.requests[0]
    assert body["format"] == schema and body["stream"] is False and body["messages"] == MSGS
    assert body["options"] == {"temperature": 0.0, "seed": 7, "num_predict": 99}


def test_ollama_missing_model(serve: Callable[[Route], FakeServer]) -> None:
    srv = serve(ollama_route)
    with pytest.raises(ModelNotFoundError) as e:
        ParamAdvisor(OllamaBackend("missing", base_url=srv.url), cache=None).advise(MSGS)
    assert "ollama pull missing" in str(e.value)
    assert len(srv.requests) == 1  # not retried


def test_ollama_500_then_success(serve: Callable[[Route], FakeServer]) -> None:
    srv = serve(ollama_route)
    adv = ParamAdvisor(
        OllamaBackend("flaky", base_url=srv.url), cache=None, retry=RetryPolicy(backoff_s=0.01), sleep=lambda s: None
    )
    a = adv.advise(MSGS)
    assert not a.fallback and [x.error_kind for x in a.attempts] == ["transport", None]


def test_ollama_think_reply(serve: Callable[[Route], FakeServer]) -> None:
    srv = serve(ollama_route)
    a = ParamAdvisor(OllamaBackend("thinker", base_url=srv.url), cache=None).advise(MSGS)
    assert not a.fallback and a.reply.k_np == 20


def test_ollama_timeout(serve: Callable[[Route], FakeServer]) -> None:
    srv = serve(ollama_route)
    with pytest.raises(LLMTimeoutError):
        OllamaBackend("slow", base_url=srv.url).complete(MSGS, schema=None, settings=DecodingSettings(), timeout_s=0.2)
    adv = ParamAdvisor(
        OllamaBackend("slow", base_url=srv.url),
        cache=None,
        retry=RetryPolicy(max_attempts=2, timeout_s=0.2),
        sleep=lambda s: None,
    )
    with pytest.raises(RequestFailedError, match=r"2 attempts \(timeout, timeout\).*no reply within 0.2 s"):
        adv.advise(MSGS)  # not a fallback: the scenario is left unstored and retried by a rerun


def test_ollama_unreachable() -> None:
    be = OllamaBackend("llama3.1:8b", base_url=f"http://127.0.0.1:{free_port()}")
    with pytest.raises(BackendUnavailableError) as e:
        be.complete(MSGS, schema=None, settings=DecodingSettings(), timeout_s=2)
    assert "ollama serve" in str(e.value)
    with pytest.raises(BackendUnavailableError):
        ParamAdvisor(be, cache=None, retry=RetryPolicy(max_attempts=2), sleep=lambda s: None).advise(MSGS)


def test_ollama_malformed_envelope(serve: Callable[[Route], FakeServer]) -> None:
    srv = serve(lambda p, b, n: (200, {"done": True}))
    with pytest.raises(LLMTransportError):
        OllamaBackend("x", base_url=srv.url).complete(MSGS, schema=None, settings=DecodingSettings(), timeout_s=2)


# --- OpenAI-compatible -------------------------------------------------------------------------


def openai_ok(content: str) -> dict[str, Any]:
    return {
        "id": "c1",
        "object": "chat.completion",
        "model": "m",
        "choices": [{"index": 0, "message": {"role": "assistant", "content": content}, "finish_reason": "stop"}],
        "usage": {"prompt_tokens": 30, "completion_tokens": 12, "total_tokens": 42},
    }


def test_openai_json_schema_and_key(serve: Callable[[Route], FakeServer], monkeypatch: pytest.MonkeyPatch) -> None:
    srv = serve(lambda p, b, n: (200, openai_ok(json.dumps(GOOD))))
    monkeypatch.setenv("OPENAI_API_KEY", "sk-test")
    be = OpenAICompatBackend("m", base_url=srv.url + "/v1")
    r = be.complete(MSGS, schema=reply_json_schema("fast"), settings=DecodingSettings(), timeout_s=5)
    assert r.parsed == GOOD and (r.prompt_tokens, r.completion_tokens) == (30, 12)
    path, body = srv.requests[0]
    assert path == "/v1/chat/completions" and body["temperature"] == 0.0 and body["stream"] is False
    assert body["response_format"]["type"] == "json_schema"
    assert body["response_format"]["json_schema"]["schema"] == reply_json_schema("fast")


def test_openai_downgrades_response_format(serve: Callable[[Route], FakeServer]) -> None:
    def route(path: str, body: dict[str, Any], n: int) -> tuple[int, Any]:
        rf = body.get("response_format", {})
        if rf.get("type") == "json_schema":
            return 400, {
                "error": {
                    "message": "response_format type json_schema is not supported",
                    "type": "invalid_request_error",
                }
            }
        if "schema" in rf:
            return 422, {
                "detail": [{"loc": ["body", "response_format", "schema"], "msg": "extra fields not permitted"}]
            }
        return 200, openai_ok("Here: " + json.dumps(GOOD))

    srv = serve(route)
    be = OpenAICompatBackend("m", base_url=srv.url + "/v1", api_key="")
    a = ParamAdvisor(be, cache=None).advise(MSGS)
    assert not a.fallback and be.format_mode == "json_object"
    assert [b["response_format"]["type"] for _, b in srv.requests] == ["json_schema", "json_object", "json_object"]
    ParamAdvisor(be, cache=None).advise(MSGS)  # remembered: one request only
    assert len(srv.requests) == 4


def test_openai_errors(serve: Callable[[Route], FakeServer]) -> None:
    def route(path: str, body: dict[str, Any], n: int) -> tuple[int, Any]:
        return {
            "auth": (401, {"error": {"message": "Incorrect API key"}}),
            "nomodel": (404, {"error": {"message": "The model `nomodel` does not exist"}}),
            "boom": (503, {"error": {"message": "overloaded"}}),
            "long": (400, {"error": {"message": "maximum context length exceeded"}}),
        }[body["model"]]

    srv = serve(route)
    url = srv.url + "/v1"
    s = DecodingSettings()
    with pytest.raises(LLMConfigError, match="OPENAI_API_KEY"):
        OpenAICompatBackend("auth", base_url=url).complete(MSGS, schema=None, settings=s, timeout_s=2)
    with pytest.raises(ModelNotFoundError):
        OpenAICompatBackend("nomodel", base_url=url).complete(MSGS, schema=None, settings=s, timeout_s=2)
    with pytest.raises(LLMTransportError):
        OpenAICompatBackend("boom", base_url=url).complete(MSGS, schema=None, settings=s, timeout_s=2)
    with pytest.raises(LLMTransportError):  # per-request problem: falls back in a run, not fatal
        OpenAICompatBackend("long", base_url=url).complete(MSGS, schema=reply_json_schema(), settings=s, timeout_s=2)


def _modes(srv: FakeServer, since: int = 0) -> list[str]:
    """The response_format mode of each request the server saw (from request ``since`` on)."""
    out = []
    for _, body in srv.requests[since:]:
        rf = body.get("response_format", {})
        out.append("json_schema" if rf.get("type") == "json_schema" else
                   "json_object_schema" if "schema" in rf else "json_object")
    return out


def test_openai_auto_mode_moves_on_when_schema_is_ignored(serve: Callable[[Route], FakeServer]) -> None:
    def route(path: str, body: dict[str, Any], n: int) -> tuple[int, Any]:
        rf = body.get("response_format", {})
        constrained = rf.get("type") == "json_object" and "schema" in rf
        return 200, openai_ok(json.dumps(GOOD) if constrained else "Sure, I think tau should be about 1.")

    srv = serve(route)
    be = OpenAICompatBackend("m", base_url=srv.url + "/v1")
    adv = ParamAdvisor(be, cache=None)
    for k in range(DEMOTE_AFTER_NO_JSON):
        a = adv.advise(MSGS)
        assert not a.fallback and a.response is not None
        assert a.response.extra["format_mode"] == "json_object_schema"
        # each request tries the established mode first, then the next one for that request only
        assert _modes(srv, 2 * k) == ["json_schema", "json_object_schema"]
        assert be.format_mode == ("json_schema" if k + 1 < DEMOTE_AFTER_NO_JSON else "json_object_schema")
    n = len(srv.requests)
    assert not adv.advise(MSGS).fallback
    assert _modes(srv, n) == ["json_object_schema"]  # demoted for good after consecutive evidence
    fixed = OpenAICompatBackend("m", base_url=srv.url + "/v1", format_mode="json_object")
    assert ParamAdvisor(fixed, cache=None, retry=RetryPolicy(max_attempts=1)).advise(MSGS).fallback
    with pytest.raises(LLMConfigError):
        OpenAICompatBackend("m", format_mode="xml")


def test_openai_one_reply_without_json_does_not_demote(serve: Callable[[Route], FakeServer]) -> None:
    # the first reply is prose (a model slip), every later one is JSON: the mode must not change
    def route(path: str, body: dict[str, Any], n: int) -> tuple[int, Any]:
        return 200, openai_ok("Let me think about this." if n == 1 else json.dumps(GOOD))

    srv = serve(route)
    be = OpenAICompatBackend("m", base_url=srv.url + "/v1")
    adv = ParamAdvisor(be, cache=None)
    first = adv.advise(MSGS)
    assert not first.fallback and _modes(srv) == ["json_schema", "json_object_schema"]
    assert be.format_mode == "json_schema"
    for _ in range(4):
        assert not adv.advise(MSGS).fallback
    assert _modes(srv, 2) == ["json_schema"] * 4


def test_openai_streak_of_no_json_is_reset_by_a_json_reply(serve: Callable[[Route], FakeServer]) -> None:
    # json_schema fails on requests 1, 3 (2 of every 3 would not be consecutive): never demoted
    calls = {"n": 0}

    def route(path: str, body: dict[str, Any], n: int) -> tuple[int, Any]:
        if body.get("response_format", {}).get("type") != "json_schema":
            return 200, openai_ok(json.dumps(GOOD))
        calls["n"] += 1
        return 200, openai_ok("prose" if calls["n"] % 2 else json.dumps(GOOD))

    srv = serve(route)
    be = OpenAICompatBackend("m", base_url=srv.url + "/v1")
    adv = ParamAdvisor(be, cache=None)
    for _ in range(8):
        assert not adv.advise(MSGS).fallback
    assert be.format_mode == "json_schema"


def test_openai_model_without_json_in_any_mode_does_not_demote(serve: Callable[[Route], FakeServer]) -> None:
    srv = serve(lambda p, b, n: (200, openai_ok("I cannot answer that.")))
    be = OpenAICompatBackend("m", base_url=srv.url + "/v1")
    adv = ParamAdvisor(be, cache=None, retry=RetryPolicy(max_attempts=1))
    for _ in range(DEMOTE_AFTER_NO_JSON + 1):
        assert adv.advise(MSGS).fallback
    assert be.format_mode == "json_schema"  # the model failed, not the response format
    assert _modes(srv, len(srv.requests) - 3) == ["json_schema", "json_object_schema", "json_object"]


# --- Retry-After ---------------------------------------------------------------------------------


def busy_then_ok(status: int, retry_after: str, ok: Callable[[], Any]) -> Route:
    """First request: ``status`` with ``Retry-After: retry_after``; later requests: ``ok()``."""

    def route(path: str, body: dict[str, Any], n: int) -> tuple[Any, ...]:
        if n == 1:
            return status, {"error": {"message": "slow down"}}, {"Retry-After": retry_after}
        return 200, ok()

    return route


def test_parse_retry_after() -> None:
    assert parse_retry_after("1") == 1.0 and parse_retry_after(" 120 ") == 120.0 and parse_retry_after("0.5") == 0.5
    now = 1_700_000_000.0
    assert parse_retry_after(formatdate(now + 30, usegmt=True), now=now) == pytest.approx(30.0)
    assert parse_retry_after(formatdate(now - 30, usegmt=True), now=now) == 0.0  # in the past: no wait
    for junk in (None, "", "soon", "-1", "1 s", "Thu, 99 Foo 2024"):
        assert parse_retry_after(junk) is None, junk
    assert parse_retry_after("9" * 400) == float("inf")  # absurd: treated as "too long" by the advisor


@pytest.mark.parametrize("status", [429, 503])
def test_openai_retry_after_seconds_sets_the_wait(serve: Callable[[Route], FakeServer], status: int) -> None:
    srv = serve(busy_then_ok(status, "1", lambda: openai_ok(json.dumps(GOOD))))
    sleeps: list[float] = []
    adv = ParamAdvisor(
        OpenAICompatBackend("m", base_url=srv.url + "/v1"),
        cache=None,
        retry=RetryPolicy(backoff_s=0.01),
        sleep=sleeps.append,
    )
    a = adv.advise(MSGS)
    assert not a.fallback and [x.error_kind for x in a.attempts] == ["busy", None]
    assert a.attempts[0].error is not None and "Retry-After: 1 s" in a.attempts[0].error
    assert sleeps == [1.0]  # max(backoff <= 0.01 s, Retry-After 1 s)


def test_ollama_retry_after_http_date_sets_the_wait(serve: Callable[[Route], FakeServer]) -> None:
    date = formatdate(time.time() + 3, usegmt=True)  # whole seconds: 2 < wait <= 3
    ok = {"message": {"role": "assistant", "content": json.dumps(GOOD)}, "done": True}
    srv = serve(busy_then_ok(429, date, lambda: ok))
    sleeps: list[float] = []
    adv = ParamAdvisor(
        OllamaBackend("m", base_url=srv.url), cache=None, retry=RetryPolicy(backoff_s=0.01), sleep=sleeps.append
    )
    a = adv.advise(MSGS)
    assert not a.fallback and a.attempts[0].error_kind == "busy"
    assert len(sleeps) == 1 and 1.0 < sleeps[0] <= 3.0


def test_openai_429_retry_after_waits_in_real_time(serve: Callable[[Route], FakeServer]) -> None:
    srv = serve(busy_then_ok(429, "1", lambda: openai_ok(json.dumps(GOOD))))
    be = OpenAICompatBackend("m", base_url=srv.url + "/v1")
    a = ParamAdvisor(be, cache=None, retry=RetryPolicy(backoff_s=0.01)).advise(MSGS)  # the real time.sleep
    assert not a.fallback and len(srv.arrivals) == 2
    assert srv.arrivals[1] - srv.arrivals[0] >= 1.0


def test_retry_after_beyond_the_policy_stops_with_a_clear_error(serve: Callable[[Route], FakeServer]) -> None:
    srv = serve(busy_then_ok(429, "3600", lambda: openai_ok(json.dumps(GOOD))))
    adv = ParamAdvisor(OpenAICompatBackend("m", base_url=srv.url + "/v1"), cache=None, sleep=lambda s: None)
    with pytest.raises(ServerBusyError) as e:
        adv.advise(MSGS)
    assert "HTTP 429" in str(e.value) and "3600 s" in str(e.value) and len(srv.requests) == 1
