"""The configuration of one language model as a phase uses it (its key identifies the answers)."""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field

from letspi.keyed import Config
from letspi.llm.client import RetryPolicy
from letspi.llm.types import DecodingSettings


class LlmConfig(Config):
    """One language model as used by a phase: model, weights, decoding, prompt text, retries.

    ``adapter_sha256`` / ``adapter_path``: the LoRA adapter llama.cpp applies (the fine-tuned
    ``smollm2-135m-letspi``); ``prompt_style``: ``paper`` (physics + fast prompts with few-shot
    memories) or ``compact`` (``letspi.llm.compact``, what the fine-tuned model was trained on);
    ``runtime``: the embedded model's llama.cpp version and attention path
    (``letspi.llm.backends.llamacpp.LlamaRuntime.identity``; None for servers).
    """

    cosmetic: ClassVar[frozenset[str]] = frozenset({"timeout_s", "cache", "model_path", "adapter_path"})

    spec: str
    model_sha256: str | None = None
    model_path: str | None = None
    adapter_sha256: str | None = None
    adapter_path: str | None = None
    prompt_style: Literal["paper", "compact", "choice"] = "paper"
    runtime: str | None = None
    temperature: float = DecodingSettings.temperature
    seed: int = DecodingSettings.seed
    max_tokens: int = DecodingSettings.max_tokens
    use_schema: bool = True
    max_attempts: int = Field(default=RetryPolicy.max_attempts, ge=1)
    prompt_sha256: str
    timeout_s: float = RetryPolicy.timeout_s
    cache: bool = True

    def decoding(self) -> DecodingSettings:
        return DecodingSettings(temperature=self.temperature, seed=self.seed, max_tokens=self.max_tokens)
