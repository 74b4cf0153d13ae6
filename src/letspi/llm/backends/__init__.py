"""Backends implementing ``letspi.llm.types.LLMBackend`` (no optional dependency imported here)."""

from letspi.llm.backends.llamacpp import LlamaCppBackend
from letspi.llm.backends.ollama import OllamaBackend
from letspi.llm.backends.openai_compat import OpenAICompatBackend
from letspi.llm.backends.scripted import ScriptedBackend, ScriptedStep

__all__ = ["LlamaCppBackend", "OllamaBackend", "OpenAICompatBackend", "ScriptedBackend", "ScriptedStep"]
