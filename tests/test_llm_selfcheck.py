"""The llama.cpp load-time self-check and the load-aware thread choice (letspi.llm.backends.llamacpp).

The first tests are pure functions; ``test_self_check_on_this_machine`` loads the embedded SmolLM2 with the
llama-cpp-python build installed here (building nothing) and checks that batched prompt evaluation, the
path every planner uses, agrees with token-by-token evaluation on this CPU.
"""

from __future__ import annotations

import numpy as np
import pytest

from letspi.llm.backends import llamacpp
from letspi.llm.backends.llamacpp import (
    LlamaRuntime,
    choose_threads,
    compare_logits,
    self_check,
    shared_llama,
)
from letspi.llm.backends.llamacpp_open import open_llama
from letspi.llm.models import EMBEDDED_MODELS, batch_tolerance, locate_model
from letspi.llm.types import ModelSelfCheckError


def test_compare_logits_flags_an_argmax_flip_and_a_large_difference() -> None:
    seq = np.array([[1.0, 5.0, 2.0], [0.0, 1.0, 9.0]])
    rel, same, ok = compare_logits(seq.copy(), seq, tolerance=0.02)
    assert (rel, same, ok) == (0.0, True, True)
    near = seq + np.array([[0.05, 0.0, 0.0], [0.0, 0.0, 0.0]])  # 0.05 / 5 = 1 % of the largest logit
    rel, same, ok = compare_logits(near, seq, tolerance=0.02)
    assert rel == pytest.approx(0.01) and same and ok
    flipped = seq.copy()
    flipped[0, 2] = 5.5  # a near-tie resolved the other way: argmax 1 -> 2
    rel, same, ok = compare_logits(flipped, seq, tolerance=1.0)
    assert not same and not ok
    big = seq * 1.1  # argmax kept, 10 % off
    rel, same, ok = compare_logits(big, seq, tolerance=0.02)
    assert same and rel == pytest.approx(0.1) and not ok


def test_threads_follow_the_free_cpus(monkeypatch: pytest.MonkeyPatch) -> None:
    env: dict[str, str] = {}
    assert choose_threads(2, cpus=2, runnable=1, env=env) == 2  # only this thread runs: both cores
    assert choose_threads(2, cpus=2, runnable=2, env=env) == 1  # one other busy process: keep one core
    assert choose_threads(2, cpus=2, runnable=5, env=env) == 1  # never fewer than one
    assert choose_threads(4, cpus=2, runnable=1, env=env) == 2  # never more than the usable CPUs
    assert choose_threads(2, cpus=8, runnable=3, env=env) == 2  # never more than asked
    monkeypatch.setattr(llamacpp, "runnable_tasks", lambda: None)
    assert choose_threads(2, cpus=2, env=env) == 2  # unknown load: all usable CPUs
    assert choose_threads(2, cpus=2, runnable=5, env={"LETSPI_LLAMA_THREADS": "2"}) == 2
    with pytest.raises(ValueError, match="LETSPI_LLAMA_THREADS"):
        choose_threads(2, env={"LETSPI_LLAMA_THREADS": "many"})


def test_runtime_from_env_validates_and_keys_the_attention_path() -> None:
    assert LlamaRuntime.from_env({}) == LlamaRuntime(flash_attn=True, self_check="on")
    off = LlamaRuntime.from_env({"LETSPI_LLAMA_FLASH_ATTN": "0", "LETSPI_LLAMA_SELF_CHECK": "strict"})
    assert off == LlamaRuntime(flash_attn=False, self_check="strict")
    assert off.identity() != LlamaRuntime().identity() and "flash_attn=1" in LlamaRuntime().identity()
    with pytest.raises(ValueError, match="LETSPI_LLAMA_FLASH_ATTN"):
        LlamaRuntime.from_env({"LETSPI_LLAMA_FLASH_ATTN": "yes"})
    with pytest.raises(ValueError, match="LETSPI_LLAMA_SELF_CHECK"):
        LlamaRuntime.from_env({"LETSPI_LLAMA_SELF_CHECK": "maybe"})


def test_tolerances_per_model_file() -> None:
    smollm2 = locate_model("smollm2-135m")
    assert batch_tolerance(smollm2) == EMBEDDED_MODELS["smollm2-135m"].batch_tolerance == 0.02
    assert batch_tolerance(smollm2.with_name("my-model.gguf")) == 0.15
    assert batch_tolerance(smollm2, smollm2.with_name("adapter.gguf")) == pytest.approx(0.05)


def test_self_check_on_this_machine() -> None:
    """The production setting (flash attention, batched prompts) agrees with token-by-token evaluation."""
    pytest.importorskip("llama_cpp")
    path = locate_model("smollm2-135m")
    loaded = shared_llama(path, n_ctx=512, runtime=LlamaRuntime())
    check = loaded.check
    assert check.verdict == "agree", check.summary()
    assert check.mode == "batched" and check.argmax_agree and len(check.positions) == 3
    assert check.max_rel_diff <= check.tolerance


def test_the_shipped_fine_tuned_model_passes_the_self_check_batched() -> None:
    pytest.importorskip("llama_cpp")
    from letspi.llm.backends.llamacpp import LlamaCppBackend

    check = LlamaCppBackend("smollm2-135m-letspi", n_ctx=512).loaded().check
    assert check.verdict == "agree" and check.mode == "batched", check.summary()


def test_without_flash_attention_the_check_never_leaves_a_disagreeing_model_in_use() -> None:
    """Flash attention off: on a build whose batched attention (llamafile sgemm) drifts, the check sees it
    and the model is reloaded to evaluate token by token; either way what is used agrees with itself."""
    pytest.importorskip("llama_cpp")
    path = locate_model("smollm2-135m")
    raw = open_llama(path, n_ctx=512, n_threads=2, flash_attn=False)
    try:
        direct = self_check(raw, 0.02)
    finally:
        raw.close()
    loaded = shared_llama(path, n_ctx=512, runtime=LlamaRuntime(flash_attn=False, self_check="on"))
    if direct.verdict == "agree":
        assert loaded.check.mode == "batched"
    else:
        assert loaded.check.mode == "token-by-token" and loaded.check.verdict == "disagree"
        assert self_check(loaded.llm, 0.02).max_rel_diff == 0.0  # token by token on both sides now
        with pytest.raises(ModelSelfCheckError, match="refusing"):
            shared_llama(path, n_ctx=256, runtime=LlamaRuntime(flash_attn=False, self_check="strict"))
