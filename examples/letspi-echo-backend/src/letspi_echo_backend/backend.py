"""The echo backend: a valid reply built from the JSON schema letspi sends with every request."""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from typing import Any

from letspi.plugin import DecodingSettings, LLMResponse, Message, try_parse_json


def reply_from_schema(schema: dict[str, Any] | None, choice: str) -> dict[str, Any]:
    """One value per property: its default, ``choice`` when an enum offers it (else the first member),
    the middle of a number's range, ``"echo"`` for a string. ``{}`` without a schema."""
    reply: dict[str, Any] = {}
    for key, prop in (schema or {}).get("properties", {}).items():
        if "default" in prop:
            reply[key] = prop["default"]
        elif "enum" in prop:
            reply[key] = choice if choice in prop["enum"] else prop["enum"][0]
        elif prop.get("type") in ("number", "integer"):
            low = float(prop.get("minimum", 0.0))
            middle = (low + float(prop.get("maximum", low))) / 2
            reply[key] = round(middle) if prop["type"] == "integer" else middle
        elif prop.get("type") == "string":
            reply[key] = "echo"
    return reply


class EchoBackend:
    """``echo:NAME``: answers every request at once, the same way for the same schema."""

    def __init__(self, name: str) -> None:
        self.name = name

    @property
    def spec(self) -> str:
        return f"echo:{self.name}"

    def complete(self, messages: Sequence[Message], *, schema: dict[str, Any] | None,
                 settings: DecodingSettings, timeout_s: float) -> LLMResponse:
        t0 = time.perf_counter()
        text = json.dumps(reply_from_schema(schema, self.name))
        prompt_words = sum(len(m["content"].split()) for m in messages)
        return LLMResponse(text=text, parsed=try_parse_json(text), prompt_tokens=prompt_words,
                           completion_tokens=len(text.split()), latency_s=time.perf_counter() - t0,
                           model_spec=self.spec)
