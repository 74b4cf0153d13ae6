"""Ollama backend (``ollama:MODEL``) over the REST ``/api/chat``, not streamed.

The JSON schema goes in ``format`` (Ollama >= 0.5 constrains decoding with it). The server is
``$OLLAMA_HOST`` (default ``http://localhost:11434``; a bare ``host:port`` gets ``http://``).
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from typing import Any

import httpx

from letspi.llm.backends._http import error_text, pooled_client, post_json, raise_for_server_error
from letspi.llm.parse import try_parse_json
from letspi.llm.types import (
    DecodingSettings,
    LLMConfigError,
    LLMResponse,
    LLMTransportError,
    Message,
    ModelNotFoundError,
    RequestRejectedError,
)

DEFAULT_OLLAMA_HOST = "http://localhost:11434"


def ollama_base_url(host: str | None = None) -> str:
    """Normalise ``OLLAMA_HOST``-style values (``0.0.0.0:11434``, ``http://h:p/``) to a base URL."""
    raw = (host or os.environ.get("OLLAMA_HOST") or DEFAULT_OLLAMA_HOST).strip().rstrip("/")
    if "://" not in raw:
        raw = "http://" + raw
    return raw.replace("://0.0.0.0", "://127.0.0.1")  # a bind address is not a connect address


class OllamaBackend:
    """Chat with a model served by Ollama."""

    def __init__(self, model: str, *, base_url: str | None = None, client: httpx.Client | None = None) -> None:
        if not model:
            raise LLMConfigError("ollama spec needs a model name, e.g. ollama:llama3.1:8b")
        self.model = model
        self.base_url = ollama_base_url(base_url)
        self._client = client or pooled_client()

    @property
    def spec(self) -> str:
        return f"ollama:{self.model}"

    def complete(self, messages: Sequence[Message], *, schema: dict[str, Any] | None, settings: DecodingSettings,
                 timeout_s: float) -> LLMResponse:
        payload: dict[str, Any] = {
            "model": self.model, "messages": [dict(m) for m in messages], "stream": False,
            "options": {"temperature": settings.temperature, "seed": settings.seed, "num_predict": settings.max_tokens},
        }
        if schema is not None:
            payload["format"] = schema
        url = f"{self.base_url}/api/chat"
        t0 = time.perf_counter()
        resp = post_json(self._client, url, payload, timeout_s=timeout_s,
                         unreachable_hint="Is Ollama running? Start it with `ollama serve` (or set OLLAMA_HOST).")
        latency = time.perf_counter() - t0
        if resp.status_code == 404:
            msg = error_text(resp)
            if "not found" in msg.lower() or "pull" in msg.lower():
                raise ModelNotFoundError(
                    f"Ollama at {self.base_url} does not have model {self.model!r} ({msg}); "
                    f"run `ollama pull {self.model}`"
                )
            raise LLMConfigError(f"{url} returned 404 ({msg}); is {self.base_url} an Ollama server?")
        raise_for_server_error(resp, url)  # 429 and 5xx, with the server's Retry-After
        if resp.status_code >= 400:  # concerns this request (e.g. too long), not the setup
            raise RequestRejectedError(
                f"{url} rejected the request (HTTP {resp.status_code}): {error_text(resp)}", status=resp.status_code
            )
        try:
            body = resp.json()
            text = body["message"]["content"]
        except (ValueError, KeyError, TypeError) as exc:
            raise LLMTransportError(f"{url}: malformed reply envelope: {resp.text[:200]!r}") from exc
        if not isinstance(text, str):
            raise LLMTransportError(f"{url}: message.content is not a string")
        return LLMResponse(
            text=text, parsed=try_parse_json(text), prompt_tokens=int(body.get("prompt_eval_count") or 0),
            completion_tokens=int(body.get("eval_count") or 0), latency_s=latency, model_spec=self.spec,
            extra={"total_duration_ns": body.get("total_duration"), "done_reason": body.get("done_reason")},
        )
