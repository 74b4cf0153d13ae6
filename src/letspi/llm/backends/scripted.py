"""A scripted backend: a deterministic test double for control-flow tests and offline pipelines.

Each call consumes the next step: a reply text, an exception to raise, or a ``ScriptedStep`` with a
latency (one over the call's timeout raises ``LLMTimeoutError`` without sleeping); an exhausted script
repeats ``default`` (or raises if None). Calls' messages are recorded in ``calls``. ``scripted:default``
always answers ``DEFAULT_REPLY``.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from letspi.llm.parse import try_parse_json
from letspi.llm.schema import DEFAULT_REPLY
from letspi.llm.types import DecodingSettings, LLMError, LLMResponse, LLMTimeoutError, Message


@dataclass(frozen=True)
class ScriptedStep:
    """One scripted call: reply ``text`` after ``latency_s`` or raise ``error``."""

    text: str = ""
    error: LLMError | None = None
    latency_s: float = 0.01
    prompt_tokens: int = 100
    completion_tokens: int = 40


def default_reply_text() -> str:
    """``DEFAULT_REPLY`` as wire JSON."""
    return json.dumps(DEFAULT_REPLY.to_wire("physics"))


class ScriptedBackend:
    """Replays a script of replies and errors."""

    def __init__(self, steps: Iterable[str | LLMError | ScriptedStep] = (), *, default: str | None = None,
                 name: str = "test") -> None:
        self._steps = [s if isinstance(s, ScriptedStep) else self._to_step(s) for s in steps]
        self._default = default
        self.name = name
        self.calls: list[list[Message]] = []
        self.schemas: list[dict[str, Any] | None] = []

    @staticmethod
    def _to_step(item: str | LLMError) -> ScriptedStep:
        return ScriptedStep(error=item) if isinstance(item, LLMError) else ScriptedStep(text=item)

    @property
    def spec(self) -> str:
        return f"scripted:{self.name}"

    @property
    def remaining(self) -> int:
        return len(self._steps)

    def complete(self, messages: Sequence[Message], *, schema: dict[str, Any] | None, settings: DecodingSettings,
                 timeout_s: float) -> LLMResponse:
        self.calls.append(list(messages))
        self.schemas.append(schema)
        if self._steps:
            step = self._steps.pop(0)
        elif self._default is not None:
            step = ScriptedStep(text=self._default)
        else:
            raise AssertionError("ScriptedBackend: script exhausted and no default reply")
        if step.latency_s > timeout_s:
            raise LLMTimeoutError(f"{self.spec}: scripted latency {step.latency_s} s > timeout {timeout_s} s")
        if step.error is not None:
            raise step.error
        return LLMResponse(text=step.text, parsed=try_parse_json(step.text), prompt_tokens=step.prompt_tokens,
                           completion_tokens=step.completion_tokens, latency_s=step.latency_s, model_spec=self.spec)
