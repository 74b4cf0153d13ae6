"""A local OpenAI-compatible chat server with injected latency: real sockets, no model.

``POST /v1/chat/completions`` answers every request with a valid LetsPi reply whose numbers are a
function of the request's messages alone (a hash), after an injected latency, so:

* replies are deterministic: a run stores the same results however its requests interleave;
* ``jitter`` > 0 spreads latencies over ``latency_s * [1 - jitter, 1 + jitter]`` (also a function of the
  request), so requests sent in one order finish in another;
* ``slots`` bounds the requests served at once (None: a thread per connection, "many slots"); the
  others wait, as on an Ollama / llama.cpp server with that many parallel slots;
* ``fault(request)`` may answer a request with an error instead (tests: HTTP 429 with
  ``Retry-After``, HTTP 500, a dead server), and ``log`` records arrivals and completions.

HTTP/1.1 keep-alive and a deep listen backlog: 64 clients connect at once without refused
connections. ``python -m benchmarks.llm_server --port 0 --latency-ms 200`` runs it in its own
process (the benchmark does, so the server's work does not share the client's interpreter) and
prints ``listening on PORT``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

from letspi.llm.schema import FIELD_RANGES, WIRE_KEYS


@dataclass(frozen=True)
class ChatRequest:
    """One request as the server saw it. ``scenario_key``: a hash of the first user message (the
    scene; a reflection round or a corrective re-ask of one scenario shares it); ``key``: of every message."""

    body: dict[str, Any]
    key: str
    scenario_key: str
    arrived: float


@dataclass(frozen=True)
class Fault:
    """An error answer: HTTP ``status`` with ``headers`` (e.g. ``{"Retry-After": "1"}``)."""

    status: int
    message: str = "injected fault"
    headers: dict[str, str] = field(default_factory=dict)


def _digest(text: str) -> bytes:
    return hashlib.sha256(text.encode("utf-8")).digest()


def request_keys(body: dict[str, Any]) -> tuple[str, str]:
    """(key of all messages, key of the first user message) of a chat request body."""
    messages = body.get("messages") or []
    users = [m.get("content", "") for m in messages if isinstance(m, dict) and m.get("role") == "user"]
    everything = json.dumps(messages, sort_keys=True, ensure_ascii=False)
    return _digest(everything).hex()[:16], _digest(users[0] if users else everything).hex()[:16]


def reply_for(key: str) -> dict[str, Any]:
    """A valid reply (wire keys, values inside the ranges, 2 decimals) determined by ``key``."""
    raw = _digest(key)
    out: dict[str, Any] = {"why": f"deterministic reply {key[:8]}"}
    for j, (name, (lo, hi)) in enumerate(FIELD_RANGES.items()):
        u = int.from_bytes(raw[2 * j: 2 * j + 2], "big") / 65535.0
        out[WIRE_KEYS[name]] = round(lo + (hi - lo) * u, 2)
    return out


def latency_for(key: str, latency_s: float, jitter: float) -> float:
    u = int.from_bytes(_digest("latency" + key)[:4], "big") / 0xFFFFFFFF
    return max(0.0, latency_s * (1.0 - jitter + 2.0 * jitter * u))


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    request_queue_size = 1024

    def handle_error(self, request: Any, client_address: Any) -> None:
        if isinstance(sys.exc_info()[1], ConnectionError):  # a client that went away (e.g. Ctrl-C)
            return
        super().handle_error(request, client_address)


class LlmTestServer:
    """The server (see the module docstring); ``with LlmTestServer(...) as srv: srv.base_url``."""

    def __init__(self, *, latency_s: float = 0.0, jitter: float = 0.0, slots: int | None = None,
                 fault: Callable[[ChatRequest], Fault | None] | None = None, host: str = "127.0.0.1",
                 port: int = 0) -> None:
        self.latency_s = latency_s
        self.jitter = jitter
        self.fault = fault
        self._slots = threading.BoundedSemaphore(slots) if slots else None
        self._lock = threading.Lock()
        self.arrivals: list[ChatRequest] = []
        self.completed: list[tuple[float, str, int]] = []  # (time, request key, status)
        self.in_flight = 0
        self.max_in_flight = 0
        outer = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"
            # headers and body are two writes: without TCP_NODELAY the body waits for the client's
            # delayed ACK of the headers (about 40 ms per request on Linux); uvicorn sets it too
            disable_nagle_algorithm = True

            def do_POST(self) -> None:
                length = int(self.headers.get("Content-Length") or 0)
                try:
                    body = json.loads(self.rfile.read(length) or b"{}")
                except ValueError:
                    self._send(400, {"error": {"message": "body is not JSON"}})
                    return
                status, payload, headers = outer._answer(self.path, body)
                self._send(status, payload, headers)

            def do_GET(self) -> None:
                if self.path.rstrip("/").endswith("/models"):
                    self._send(200, {"object": "list", "data": [{"id": "letspi-test", "object": "model"}]})
                else:
                    self._send(404, {"error": {"message": f"no route {self.path}"}})

            def _send(self, status: int, payload: Any, headers: dict[str, str] | None = None) -> None:
                data = json.dumps(payload).encode()
                self.send_response(status)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(data)))
                for k, v in (headers or {}).items():
                    self.send_header(k, v)
                self.end_headers()
                self.wfile.write(data)

            def log_message(self, *args: Any) -> None:
                pass

        self.httpd = _Server((host, port), Handler)
        self._thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.05},
                                        name="letspi-test-llm-server", daemon=True)

    # lifecycle ---------------------------------------------------------------------------------
    def start(self) -> LlmTestServer:
        self._thread.start()
        return self

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()

    def __enter__(self) -> LlmTestServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def port(self) -> int:
        return int(self.httpd.server_address[1])

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.port}/v1"

    def spec(self, model: str = "letspi-test") -> str:
        """The letspi spec of this server (``openai:MODEL@URL``)."""
        return f"openai:{model}@{self.base_url}"

    # answering ----------------------------------------------------------------------------------
    def _answer(self, path: str, body: dict[str, Any]) -> tuple[int, Any, dict[str, str]]:
        key, scenario_key = request_keys(body)
        request = ChatRequest(body=body, key=key, scenario_key=scenario_key, arrived=time.monotonic())
        with self._lock:
            self.arrivals.append(request)
        if not path.rstrip("/").endswith("/chat/completions"):
            return 404, {"error": {"message": f"no route {path}"}}, {}
        fault = self.fault(request) if self.fault is not None else None
        if self._slots is not None:
            self._slots.acquire()
        with self._lock:
            self.in_flight += 1
            self.max_in_flight = max(self.max_in_flight, self.in_flight)
        try:
            time.sleep(latency_for(key, self.latency_s, self.jitter))
            if fault is not None:
                status, payload, headers = fault.status, {"error": {"message": fault.message}}, fault.headers
            else:
                status, payload, headers = 200, self._completion(body, key), {}
        finally:
            with self._lock:
                self.in_flight -= 1
                self.completed.append((time.monotonic(), key, status))
            if self._slots is not None:
                self._slots.release()
        return status, payload, headers

    @staticmethod
    def _completion(body: dict[str, Any], key: str) -> dict[str, Any]:
        text = json.dumps(reply_for(key))
        prompt_chars = sum(len(str(m.get("content", ""))) for m in body.get("messages") or [] if isinstance(m, dict))
        return {
            "id": f"chatcmpl-{key}", "object": "chat.completion", "created": int(time.time()),
            "model": body.get("model", "letspi-test"),
            "choices": [{"index": 0, "finish_reason": "stop", "message": {"role": "assistant", "content": text}}],
            "usage": {"prompt_tokens": prompt_chars // 4, "completion_tokens": len(text) // 4,
                      "total_tokens": prompt_chars // 4 + len(text) // 4},
        }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="letspi's OpenAI-compatible test server (injected latency)")
    parser.add_argument("--port", type=int, default=0)
    parser.add_argument("--latency-ms", type=float, default=200.0)
    parser.add_argument("--jitter", type=float, default=0.5, help="latency spread: latency x [1 - j, 1 + j]")
    parser.add_argument("--slots", type=int, default=0, help="requests served at once (0: unbounded)")
    args = parser.parse_args(argv)
    server = LlmTestServer(latency_s=args.latency_ms / 1000.0, jitter=args.jitter, slots=args.slots or None,
                           port=args.port)
    print(f"listening on {server.port}", flush=True)
    try:
        server.httpd.serve_forever(poll_interval=0.05)
    except KeyboardInterrupt:
        pass
    finally:
        server.httpd.server_close()


if __name__ == "__main__":
    main()
