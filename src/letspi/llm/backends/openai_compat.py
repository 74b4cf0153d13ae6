"""OpenAI-compatible chat backend (``openai:MODEL@http://host:port/v1``): vLLM, llama.cpp servers, LM Studio, OpenAI.

Base URL: the spec, else ``$OPENAI_BASE_URL``, else OpenAI's; key: ``api_key``, else ``$OPENAI_API_KEY``
(no header when neither is set). ``format_mode="auto"`` tries ``FORMAT_MODES`` in order, moving on for good
when the server rejects a format by name (400/422, or 500 with a validation error), for one request when a
reply holds no JSON, and for good after ``DEMOTE_AFTER_NO_JSON`` consecutive requests where only a simpler
mode gave JSON. The mode used is in ``LLMResponse.extra["format_mode"]``.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Sequence
from typing import Any, Final

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

DEFAULT_OPENAI_BASE_URL: Final = "https://api.openai.com/v1"
FORMAT_MODES: Final = ("json_schema", "json_object_schema", "json_object")
_FORMAT_WORDS: Final = ("response_format", "json_schema", "schema", "json_object")
#: Consecutive requests without JSON in the established mode (with JSON in a simpler one) that demote it for good.
DEMOTE_AFTER_NO_JSON: Final = 3


def _response_format(mode: str, schema: dict[str, Any]) -> dict[str, Any]:
    if mode == "json_schema":
        return {"type": "json_schema", "json_schema": {"name": "letspi_reply", "schema": schema, "strict": True}}
    if mode == "json_object_schema":
        return {"type": "json_object", "schema": schema}
    return {"type": "json_object"}


class OpenAICompatBackend:
    """Chat with any server that speaks OpenAI's ``/chat/completions``."""

    def __init__(self, model: str, *, base_url: str | None = None, api_key: str | None = None,
                 client: httpx.Client | None = None, format_mode: str = "auto") -> None:
        if format_mode != "auto" and format_mode not in FORMAT_MODES:
            raise LLMConfigError(f"format_mode must be 'auto' or one of {FORMAT_MODES}, got {format_mode!r}")
        if not model:
            raise LLMConfigError("openai spec needs a model name, e.g. openai:gpt-4o-mini@https://api.openai.com/v1")
        self.model = model
        self.base_url = (base_url or os.environ.get("OPENAI_BASE_URL") or DEFAULT_OPENAI_BASE_URL).rstrip("/")
        self._api_key = api_key if api_key is not None else os.environ.get("OPENAI_API_KEY")
        self._client = client or pooled_client()
        self._auto = format_mode == "auto"
        # index into FORMAT_MODES of the established mode (auto: the first one not yet rejected)
        self._mode_index = 0 if self._auto else FORMAT_MODES.index(format_mode)
        self._no_json_streak = 0  # see module docstring
        self._lock = threading.Lock()  # guards the two fields above (requests may run in threads)

    @property
    def spec(self) -> str:
        return f"openai:{self.model}@{self.base_url}"

    @property
    def format_mode(self) -> str:
        """The established structured-output mode."""
        return FORMAT_MODES[self._mode_index]

    def complete(self, messages: Sequence[Message], *, schema: dict[str, Any] | None, settings: DecodingSettings,
                 timeout_s: float) -> LLMResponse:
        url = f"{self.base_url}/chat/completions"
        headers = {"Authorization": f"Bearer {self._api_key}"} if self._api_key else None
        t0 = time.perf_counter()
        with self._lock:
            established = self._mode_index
        mode = established
        skipped_no_json = False  # this request moved past a mode whose reply had no JSON
        while True:
            resp = post_json(self._client, url, self._payload(messages, settings, schema, mode), timeout_s=timeout_s,
                             headers=headers,
                             unreachable_hint="Is the OpenAI-compatible server running at that address?")
            can_downgrade = self._auto and schema is not None and mode < len(FORMAT_MODES) - 1
            if can_downgrade and resp.status_code in (400, 422, 500):
                msg = error_text(resp).lower()
                if any(word in msg for word in _FORMAT_WORDS):
                    mode += 1  # the server does not take that response_format: for good
                    with self._lock:
                        self._mode_index = max(self._mode_index, mode)
                    continue
            if can_downgrade and resp.status_code == 200 and self._reply_has_no_json(resp):
                mode += 1  # accepted but no JSON came back: the next mode, for this request only
                skipped_no_json = True
                continue
            break
        if self._auto and schema is not None and resp.status_code == 200:
            self._count_no_json(established, mode, skipped_no_json, self._reply_has_no_json(resp))
        latency = time.perf_counter() - t0
        self._raise_for_status(resp, url)
        return self._response(resp, url, latency, FORMAT_MODES[mode] if schema is not None else None)

    def _payload(self, messages: Sequence[Message], settings: DecodingSettings, schema: dict[str, Any] | None,
                 mode: int) -> dict[str, Any]:
        """The chat-completions request body, with the structured-output request of format ``mode``."""
        payload: dict[str, Any] = {
            "model": self.model, "messages": [dict(m) for m in messages], "temperature": settings.temperature,
            "seed": settings.seed, "max_tokens": settings.max_tokens, "stream": False,
        }
        if schema is not None:
            payload["response_format"] = _response_format(FORMAT_MODES[mode], schema)
        return payload

    def _response(self, resp: httpx.Response, url: str, latency: float, format_mode: str | None) -> LLMResponse:
        """The reply text, parsed JSON and token counts of a successful response."""
        try:
            body = resp.json()
            text = body["choices"][0]["message"]["content"]
        except (ValueError, KeyError, IndexError, TypeError) as exc:
            raise LLMTransportError(f"{url}: malformed reply envelope: {resp.text[:200]!r}") from exc
        if not isinstance(text, str):
            raise LLMTransportError(f"{url}: choices[0].message.content is not a string")
        usage = body.get("usage") or {}
        return LLMResponse(text=text, parsed=try_parse_json(text), prompt_tokens=int(usage.get("prompt_tokens") or 0),
                           completion_tokens=int(usage.get("completion_tokens") or 0), latency_s=latency,
                           model_spec=self.spec, extra={"format_mode": format_mode})

    def _count_no_json(self, established: int, used: int, skipped: bool, final_has_no_json: bool) -> None:
        """Track consecutive no-JSON replies in the established mode; demote after enough of them."""
        with self._lock:
            if self._mode_index != established:
                return  # another request changed the mode meanwhile: its evidence is newer
            if not skipped:
                self._no_json_streak = 0  # the established mode gave JSON (or nothing simpler to try)
            elif not final_has_no_json:  # no JSON in the established mode, JSON in a simpler one
                self._no_json_streak += 1
                if self._no_json_streak >= DEMOTE_AFTER_NO_JSON:
                    self._mode_index = used
                    self._no_json_streak = 0

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
        raise_for_server_error(resp, url)  # 429 and 5xx, with the server's Retry-After
        # other 4xx (e.g. a prompt over the context) concern this request: it falls back (a retry is refused too)
        raise RequestRejectedError(f"{url}: request rejected (HTTP {code}): {msg}", status=code)
