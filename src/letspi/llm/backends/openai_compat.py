"""OpenAI-compatible chat backend (``openai:MODEL@http://host:port/v1``).

Works with vLLM, the llama.cpp server, llama-cpp-python's server, LM Studio and OpenAI. The
base URL comes from the spec, else ``$OPENAI_BASE_URL``, else OpenAI's; the key from the
``api_key`` argument, else ``$OPENAI_API_KEY`` (no header when neither is set: local servers
do not need one).

Structured output: servers disagree on ``response_format``. We try, in order,
``{"type": "json_schema", ...}`` (OpenAI, vLLM, LM Studio, llama.cpp server),
``{"type": "json_object", "schema": ...}`` (llama-cpp-python's server) and plain
``{"type": "json_object"}``, moving on when the server rejects the request with an error that
names the response format (400/422; llama-cpp-python's server answers 500 with a validation
error), and remember what worked for the rest of the backend's life. In this ``"auto"`` mode a
reply that contains no JSON object at all also moves on to the next mode (resending at once),
for servers that ignore a format they do not know. ``format_mode=...`` fixes the mode.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from typing import Any, Final

import httpx

from letspi.llm.backends._http import error_text, post_json
from letspi.llm.parse import try_parse_json
from letspi.llm.types import (
    DecodingSettings,
    LLMConfigError,
    LLMResponse,
    LLMTransportError,
    Message,
    ModelNotFoundError,
)

DEFAULT_OPENAI_BASE_URL: Final = "https://api.openai.com/v1"
FORMAT_MODES: Final = ("json_schema", "json_object_schema", "json_object")
_FORMAT_WORDS: Final = ("response_format", "json_schema", "schema", "json_object")


def _response_format(mode: str, schema: dict[str, Any]) -> dict[str, Any]:
    if mode == "json_schema":
        return {"type": "json_schema", "json_schema": {"name": "letspi_reply", "schema": schema, "strict": True}}
    if mode == "json_object_schema":
        return {"type": "json_object", "schema": schema}
    return {"type": "json_object"}


class OpenAICompatBackend:
    """Chat with any server that speaks OpenAI's ``/chat/completions``."""

    def __init__(
        self,
        model: str,
        *,
        base_url: str | None = None,
        api_key: str | None = None,
        client: httpx.Client | None = None,
        format_mode: str = "auto",
    ) -> None:
        if format_mode != "auto" and format_mode not in FORMAT_MODES:
            raise LLMConfigError(f"format_mode must be 'auto' or one of {FORMAT_MODES}, got {format_mode!r}")
        if not model:
            raise LLMConfigError("openai spec needs a model name, e.g. openai:gpt-4o-mini@https://api.openai.com/v1")
        self.model = model
        self.base_url = (base_url or os.environ.get("OPENAI_BASE_URL") or DEFAULT_OPENAI_BASE_URL).rstrip("/")
        self._api_key = api_key if api_key is not None else os.environ.get("OPENAI_API_KEY")
        self._client = client or httpx.Client()
        self._auto = format_mode == "auto"
        # index into FORMAT_MODES of the mode in use (auto: the first one not yet rejected)
        self._mode_index = 0 if self._auto else FORMAT_MODES.index(format_mode)

    @property
    def spec(self) -> str:
        return f"openai:{self.model}@{self.base_url}"

    @property
    def format_mode(self) -> str:
        """The structured-output mode in use (changes after a server rejects one)."""
        return FORMAT_MODES[self._mode_index]

    def complete(
        self,
        messages: Sequence[Message],
        *,
        schema: dict[str, Any] | None,
        settings: DecodingSettings,
        timeout_s: float,
    ) -> LLMResponse:
        url = f"{self.base_url}/chat/completions"
        headers = {"Authorization": f"Bearer {self._api_key}"} if self._api_key else None
        t0 = time.perf_counter()
        while True:
            payload: dict[str, Any] = {
                "model": self.model,
                "messages": [dict(m) for m in messages],
                "temperature": settings.temperature,
                "seed": settings.seed,
                "max_tokens": settings.max_tokens,
                "stream": False,
            }
            if schema is not None:
                payload["response_format"] = _response_format(self.format_mode, schema)
            resp = post_json(
                self._client,
                url,
                payload,
                timeout_s=timeout_s,
                headers=headers,
                unreachable_hint="Is the OpenAI-compatible server running at that address?",
            )
            can_downgrade = self._auto and schema is not None and self._mode_index < len(FORMAT_MODES) - 1
            if can_downgrade and resp.status_code in (400, 422, 500):
                msg = error_text(resp).lower()
                if any(word in msg for word in _FORMAT_WORDS):
                    self._mode_index += 1  # this server does not take that response_format: downgrade
                    continue
            if can_downgrade and resp.status_code == 200 and self._reply_has_no_json(resp):
                self._mode_index += 1  # accepted but ignored (no JSON came back): try the next mode
                continue
            break
        latency = time.perf_counter() - t0
        self._raise_for_status(resp, url)
        try:
            body = resp.json()
            text = body["choices"][0]["message"]["content"]
        except (ValueError, KeyError, IndexError, TypeError) as exc:
            raise LLMTransportError(f"{url}: malformed reply envelope: {resp.text[:200]!r}") from exc
        if not isinstance(text, str):
            raise LLMTransportError(f"{url}: choices[0].message.content is not a string")
        usage = body.get("usage") or {}
        return LLMResponse(
            text=text,
            parsed=try_parse_json(text),
            prompt_tokens=int(usage.get("prompt_tokens") or 0),
            completion_tokens=int(usage.get("completion_tokens") or 0),
            latency_s=latency,
            model_spec=self.spec,
            extra={"format_mode": self.format_mode if schema is not None else None},
        )

    @staticmethod
    def _reply_has_no_json(resp: httpx.Response) -> bool:
        try:
            text = resp.json()["choices"][0]["message"]["content"]
        except (ValueError, KeyError, IndexError, TypeError):
            return False  # a malformed envelope is reported by the caller
        return isinstance(text, str) and try_parse_json(text) is None

    def _raise_for_status(self, resp: httpx.Response, url: str) -> None:
        code = resp.status_code
        if code < 400:
            return
        msg = error_text(resp)
        if code in (401, 403):
            raise LLMConfigError(f"{url}: HTTP {code} ({msg}); check OPENAI_API_KEY")
        if code == 404:
            if "model" in msg.lower():
                raise ModelNotFoundError(f"{url}: model {self.model!r} not found ({msg})")
            raise LLMConfigError(f"{url}: HTTP 404 ({msg}); does the base URL end in /v1?")
        if code == 429 or code >= 500:
            raise LLMTransportError(f"{url}: HTTP {code}: {msg}")
        # Other 4xx (e.g. prompt longer than the context) concern this request, not the setup:
        # treat as a failed call so a long run falls back instead of stopping.
        raise LLMTransportError(f"{url}: request rejected (HTTP {code}): {msg}")
