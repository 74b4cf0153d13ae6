"""Embedded llama.cpp backend (llama-cpp-python), for ``llamacpp:MODEL`` specs.

* A LoRA adapter GGUF (``lora_path``; ``llamacpp:smollm2-135m-letspi`` finds its own, see
  ``letspi.llm.models.locate_adapter``) is applied by llama.cpp when the model is loaded.
* One ``Llama`` instance per (model file, adapter, context size) per process, shared by every backend
  object: loading is cheap but llama.cpp keeps the previous prompt's KV cache, so consecutive
  calls that share a static prompt prefix only evaluate the changed tail (REFERENCE §8).
* Decoding is constrained by the JSON schema (``response_format={"type": "json_object",
  "schema": ...}``), greedy (temperature 0) with a fixed seed, on ``n_threads`` threads.
* Timeouts: generation is streamed and abandoned when the deadline passes
  (``LLMTimeoutError``); prompt evaluation itself cannot be interrupted.
* AMX workaround: llama.cpp wheels built with ``GGML_NATIVE`` on CPUs that advertise AMX use AMX
  tile instructions through "extra buffer types". In VMs that advertise AMX without enabling its
  register state (these machines) ``ldtilecfg`` faults and the process dies with SIGSEGV on the
  first multi-token prompt. When the loaded llama.cpp reports AMX support we therefore load
  models with ``use_extra_bufts = False``, which also gives up the weight-repacking speedup.
  ``LETSPI_LLAMA_EXTRA_BUFTS=1`` keeps extra buffer types, ``=0`` always disables them. A wheel
  built without AMX (``CMAKE_ARGS="-DGGML_NATIVE=OFF -DGGML_AVX2=ON -DGGML_AVX512=ON ...
  -DGGML_AMX_TILE=OFF -DGGML_AMX_INT8=OFF -DGGML_AMX_BF16=OFF"``) needs no workaround and keeps
  the repacking.
"""

from __future__ import annotations

import atexit
import os
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from letspi.llm.models import locate_adapter, locate_model
from letspi.llm.parse import try_parse_json
from letspi.llm.types import (
    DecodingSettings,
    LLMResponse,
    LLMTimeoutError,
    LLMTransportError,
    Message,
    MissingDependencyError,
    RequestRejectedError,
)

_INSTALL_HINT = (
    "the llamacpp backend needs llama-cpp-python: pip install llama-cpp-python "
    "(builds from source, about 6 min on 2 cores)"
)

# (model path, adapter path or "", n_ctx, n_threads) -> (Llama, lock). Filled lazily; never at import.
_INSTANCES: dict[tuple[str, str, int, int], tuple[Any, threading.Lock]] = {}
_INSTANCES_LOCK = threading.Lock()


def _import_llama_cpp() -> Any:
    try:
        import llama_cpp
        import llama_cpp.llama
    except ImportError as exc:
        raise MissingDependencyError(f"{_INSTALL_HINT} ({exc})") from None
    return llama_cpp


def amx_compiled_in(llama_mod: Any) -> bool:
    """Whether the loaded llama.cpp CPU backend was built with AMX kernels."""
    try:
        info = llama_mod.llama_print_system_info()
    except (AttributeError, OSError):
        return False
    text = info.decode(errors="replace") if isinstance(info, bytes) else str(info)
    return "AMX_INT8 = 1" in text or "AMX_TILE = 1" in text or "AMX_BF16 = 1" in text


def extra_buffer_types_disabled(llama_mod: Any) -> bool:
    """The decision of the AMX workaround (see module docstring)."""
    setting = os.environ.get("LETSPI_LLAMA_EXTRA_BUFTS", "auto")
    if setting in ("0", "1"):
        return setting == "0"
    return amx_compiled_in(llama_mod)


@contextmanager
def without_extra_buffer_types(llama_mod: Any) -> Iterator[None]:
    """Make ``Llama(...)`` load with ``use_extra_bufts = False`` if needed (see module docstring)."""
    if not extra_buffer_types_disabled(llama_mod):
        yield
        return
    low = llama_mod.llama.llama_cpp  # the ctypes binding module that Llama.__init__ calls
    original = low.llama_model_default_params

    def patched() -> Any:
        params = original()
        if hasattr(params, "use_extra_bufts"):
            params.use_extra_bufts = False
        return params

    low.llama_model_default_params = patched
    try:
        yield
    finally:
        low.llama_model_default_params = original


def shared_llama(
    model_path: Path, *, n_ctx: int = 4096, n_threads: int = 2, seed: int = 0, lora_path: Path | None = None
) -> tuple[Any, threading.Lock]:
    """The process-wide ``Llama`` for this model file (and LoRA adapter) and its lock (created on first use)."""
    key = (str(model_path), str(lora_path or ""), n_ctx, n_threads)
    with _INSTANCES_LOCK:
        hit = _INSTANCES.get(key)
        if hit is not None:
            return hit
        llama_mod = _import_llama_cpp()
        with without_extra_buffer_types(llama_mod):
            llm = llama_mod.Llama(
                model_path=str(model_path),
                n_ctx=n_ctx,
                n_threads=n_threads,
                n_threads_batch=n_threads,
                seed=seed,
                lora_path=str(lora_path) if lora_path is not None else None,
                verbose=False,
            )
        # free the model before interpreter teardown: llama_cpp's __del__ fails noisily once its
        # module globals are gone
        atexit.register(llm.close)
        entry = (llm, threading.Lock())
        _INSTANCES[key] = entry
        return entry


class LlamaCppBackend:
    """``llamacpp:gemma3-270m``, ``llamacpp:smollm2-135m``, ``llamacpp:smollm2-135m-letspi`` or
    ``llamacpp:/path/model.gguf``. ``lora_path``: a LoRA adapter GGUF (default: the fine-tuned model's
    own, ``locate_adapter``; None for the others)."""

    def __init__(
        self, model: str, *, n_ctx: int = 4096, n_threads: int = 2, lora_path: Path | str | None = None
    ) -> None:
        self.model = model
        self.n_ctx = n_ctx
        self.n_threads = n_threads
        _import_llama_cpp()  # fail fast with the pip hint
        self.model_path = locate_model(model)
        self.lora_path = Path(lora_path) if lora_path is not None else locate_adapter(model)

    @property
    def spec(self) -> str:
        return f"llamacpp:{self.model}"

    def load(self) -> None:
        """Load the model now (otherwise the first call does): callers time loading apart from inference."""
        shared_llama(self.model_path, n_ctx=self.n_ctx, n_threads=self.n_threads, lora_path=self.lora_path)

    def complete(
        self,
        messages: Sequence[Message],
        *,
        schema: dict[str, Any] | None,
        settings: DecodingSettings,
        timeout_s: float,
    ) -> LLMResponse:
        llm, lock = shared_llama(self.model_path, n_ctx=self.n_ctx, n_threads=self.n_threads, seed=settings.seed,
                                 lora_path=self.lora_path)
        response_format: dict[str, Any] | None = None
        if schema is not None:
            response_format = {"type": "json_object", "schema": schema}
        with lock:  # one generation at a time per model: the KV cache is shared state
            t0 = time.perf_counter()
            deadline = t0 + timeout_s
            parts: list[str] = []
            try:
                stream = llm.create_chat_completion(
                    messages=[dict(m) for m in messages],
                    temperature=settings.temperature,
                    seed=settings.seed,
                    max_tokens=settings.max_tokens,
                    response_format=response_format,
                    stream=True,
                )
                for chunk in stream:
                    delta = chunk["choices"][0].get("delta", {})
                    text = delta.get("content")
                    if text:
                        parts.append(text)
                    if time.perf_counter() > deadline:
                        stream.close()
                        raise LLMTimeoutError(
                            f"{self.spec}: no complete reply within {timeout_s:.1f} s ({len(parts)} tokens)"
                        )
            except LLMTimeoutError:
                raise
            except ValueError as exc:  # the prompt does not fit the context: this request only
                raise RequestRejectedError(f"{self.spec}: {exc}") from exc
            except RuntimeError as exc:  # llama_decode errors
                raise LLMTransportError(f"{self.spec}: {exc}") from exc
            latency = time.perf_counter() - t0
            completion_tokens = len(parts)  # streaming yields one chunk per generated token
            prompt_tokens = max(int(llm.n_tokens) - completion_tokens, 0)
        text = "".join(parts)
        return LLMResponse(
            text=text,
            parsed=try_parse_json(text),
            prompt_tokens=prompt_tokens,
            completion_tokens=completion_tokens,
            latency_s=latency,
            model_spec=self.spec,
        )
