"""The configuration of one language model as a phase uses it (its key identifies the answers)."""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field

from letspi.keyed import Config
from letspi.llm.client import RetryPolicy
from letspi.llm.types import DecodingSettings


class LlmConfig(Config):
    """One language model as used by a phase: model, weights (``adapter_*``: the LoRA adapter llama.cpp applies),
    decoding, ``prompt_style`` (``PROMPT_STYLES``), retries; ``runtime``: the embedded model's
    ``LlamaRuntime.identity`` (None for servers)."""

    cosmetic: ClassVar[frozenset[str]] = frozenset({"timeout_s", "cache", "model_path", "adapter_path"})
    omitted_when_none: ClassVar[frozenset[str]] = frozenset({"backend"})

    spec: str
    #: "package VERSION" of a backend kind from an installed package (None: built in)
    backend: str | None = None
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
