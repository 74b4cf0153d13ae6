"""The embedded SmolLM2 runs from an F16 copy of the packaged Q4_1 file (``letspi.llm.models.runtime_copy``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from letspi.llm.backends.llamacpp import _last_logits
from letspi.llm.backends.llamacpp_open import open_llama
from letspi.llm.models import (
    EMBEDDED_MODELS,
    SMOLLM2_RUNTIME_FORMAT,
    batch_tolerance,
    file_fingerprint,
    locate_model,
    packaged_smollm2_path,
    runtime_copy,
)


@pytest.fixture(scope="module")
def packaged() -> Path:
    pytest.importorskip("llama_cpp")
    try:
        return packaged_smollm2_path()
    except Exception as exc:  # the model package is optional in some environments
        pytest.skip(str(exc))


def test_the_embedded_names_locate_the_runtime_copy_not_the_packaged_file(packaged: Path) -> None:
    for name in ("smollm2-135m", "smollm2-135m-letspi"):
        path = locate_model(name)
        assert path != packaged and path.name.endswith(f".{SMOLLM2_RUNTIME_FORMAT}.gguf"), path
        assert file_fingerprint(packaged) in path.name  # another source file gets another copy
    assert batch_tolerance(locate_model("smollm2-135m")) == EMBEDDED_MODELS["smollm2-135m"].batch_tolerance


def test_conversion_happens_once_and_keeps_the_weights(packaged: Path, tmp_path: Path) -> None:
    copy = runtime_copy(packaged, "F16", cache_dir=tmp_path)
    assert copy.parent == tmp_path / "models" and copy.is_file()
    assert copy.stat().st_size > 2 * packaged.stat().st_size  # 16 bits per weight against ~5
    assert not list(copy.parent.glob("*.part"))  # the temporary file was renamed, not left behind
    mtime = copy.stat().st_mtime_ns
    assert runtime_copy(packaged, "F16", cache_dir=tmp_path) == copy and copy.stat().st_mtime_ns == mtime

    def last_logits(path: Path) -> np.ndarray:
        llm = open_llama(path, n_ctx=128, n_threads=2, fallback=False)  # the Q4_1 file itself, never its copy
        try:
            llm.eval(llm.tokenize(b"The car ahead brakes hard, so the ego car"))
            return _last_logits(llm)
        finally:
            llm.close()

    q4, f16 = last_logits(packaged), last_logits(copy)
    # the same model: the next-token distribution peaks at the same tokens and differs only by the
    # activation quantization Q4_1 kernels apply (F16 keeps the dequantized weights)
    assert np.argmax(q4) == np.argmax(f16)
    assert set(np.argsort(q4)[-5:]) == set(np.argsort(f16)[-5:])
    assert np.corrcoef(q4, f16)[0, 1] > 0.99


def test_an_unknown_format_is_one_clear_error(packaged: Path, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown runtime model format 'Q2_K'; known: F16, Q8_0"):
        runtime_copy(packaged, "Q2_K", cache_dir=tmp_path)
    assert not (tmp_path / "models").exists()
