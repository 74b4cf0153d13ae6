"""The llama.cpp backend without a model (the end-to-end tests are slow: tests/test_llm_embedded.py)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest

from letspi.llm.backends.llamacpp_open import amx_compiled_in, extra_buffer_types_disabled, without_extra_buffer_types


def _fake_llama(system_info: bytes) -> Any:
    params = SimpleNamespace(use_extra_bufts=True)
    low = SimpleNamespace(llama_model_default_params=lambda: SimpleNamespace(**vars(params)))
    return SimpleNamespace(llama_print_system_info=lambda: system_info, llama=SimpleNamespace(llama_cpp=low))


def test_amx_detection_reads_the_system_info() -> None:
    assert amx_compiled_in(_fake_llama(b"CPU : SSE3 = 1 | AVX2 = 1 | AMX_INT8 = 1 |"))
    assert not amx_compiled_in(_fake_llama(b"CPU : SSE3 = 1 | AVX2 = 1 | AMX_INT8 = 0 |"))
    assert not amx_compiled_in(SimpleNamespace())  # an old binding without the call


def test_extra_buffer_types_are_off_only_with_amx_unless_overridden(monkeypatch: pytest.MonkeyPatch) -> None:
    amx, plain = _fake_llama(b"AMX_TILE = 1"), _fake_llama(b"AVX2 = 1")
    monkeypatch.delenv("LETSPI_LLAMA_EXTRA_BUFTS", raising=False)
    assert extra_buffer_types_disabled(amx) and not extra_buffer_types_disabled(plain)
    with without_extra_buffer_types(amx):
        assert amx.llama.llama_cpp.llama_model_default_params().use_extra_bufts is False
    assert amx.llama.llama_cpp.llama_model_default_params().use_extra_bufts is True  # restored
    monkeypatch.setenv("LETSPI_LLAMA_EXTRA_BUFTS", "1")
    assert not extra_buffer_types_disabled(amx)
    monkeypatch.setenv("LETSPI_LLAMA_EXTRA_BUFTS", "0")
    assert extra_buffer_types_disabled(plain)
