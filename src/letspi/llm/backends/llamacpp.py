"""Embedded llama.cpp backend (llama-cpp-python), for ``llamacpp:MODEL`` specs.

* One ``Llama`` per (model file, LoRA adapter, context size, runtime) per process, shared by every backend
  object: llama.cpp keeps the KV cache, so calls sharing a prompt prefix only evaluate the changed tail.
* Decoding: greedy, seeded, constrained by the JSON schema; generation is streamed and abandoned at the
  deadline (``LLMTimeoutError``); prompt evaluation itself cannot be interrupted.
* Flash attention (``LETSPI_LLAMA_FLASH_ATTN=0``: off), the self-check at load (``self_check``) and the
  threads chosen per call (``choose_threads``) are explained in docs/llm.md.
"""

from __future__ import annotations

import atexit
import os
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final, Literal

import numpy as np

from letspi.llm.backends.llamacpp_open import import_llama_cpp, llama_cpp_version, open_llama, runnable_model
from letspi.llm.models import batch_tolerance, file_fingerprint, locate_adapter, locate_model
from letspi.llm.parse import try_parse_json
from letspi.llm.types import (
    DecodingSettings,
    LLMResponse,
    LLMTimeoutError,
    LLMTransportError,
    Message,
    ModelSelfCheckError,
    RequestRejectedError,
)

FLASH_ATTN_ENV: Final = "LETSPI_LLAMA_FLASH_ATTN"
THREADS_ENV: Final = "LETSPI_LLAMA_THREADS"
SELF_CHECK_ENV: Final = "LETSPI_LLAMA_SELF_CHECK"
DEFAULT_MAX_THREADS: Final = 2

#: A fixed prompt for the self-check: plain text (any model), with confident next tokens.
CHECK_TEXT: Final = (
    "A car drives at 30 m/s on a highway with three lanes. The car ahead is 20 m away and brakes hard. "
    "To avoid a collision the driver must brake or change lanes. One, two, three, four, five, six, seven"
)


# --- runtime settings --------------------------------------------------------------------------


@dataclass(frozen=True)
class LlamaRuntime:
    """llama.cpp options that can change an answer (keyed via ``identity``). ``self_check``: ``on`` (fall back
    to token-by-token evaluation on disagreement), ``strict`` (refuse) or ``off``."""

    flash_attn: bool = True
    self_check: Literal["on", "strict", "off"] = "on"

    @classmethod
    def from_env(cls, env: dict[str, str] | None = None) -> LlamaRuntime:
        env = dict(os.environ) if env is None else env
        fa = env.get(FLASH_ATTN_ENV, "1").strip()
        if fa not in ("0", "1"):
            raise ValueError(f"${FLASH_ATTN_ENV} must be 0 or 1, got {fa!r}")
        check = env.get(SELF_CHECK_ENV, "on").strip().lower()
        if check not in ("on", "strict", "off"):
            raise ValueError(f"${SELF_CHECK_ENV} must be on, strict or off, got {check!r}")
        return cls(flash_attn=fa == "1", self_check=check)  # type: ignore[arg-type]

    def identity(self) -> str:
        """What enters keys: the library version and the attention path (not the check's fallback, which
        gives the logits a passing check would)."""
        return f"llama-cpp-python={llama_cpp_version()};flash_attn={int(self.flash_attn)}"


def available_cpus() -> int:
    """CPUs this process may run on (affinity / cgroup cpuset), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def runnable_tasks() -> int | None:
    """Tasks runnable on the whole machine right now (``/proc/loadavg``'s 4th field), None if unknown."""
    try:
        with open("/proc/loadavg", encoding="ascii") as fh:
            running = fh.read().split()[3].split("/")[0]
        return int(running)
    except (OSError, IndexError, ValueError):
        return None


def choose_threads(max_threads: int, *, cpus: int | None = None, runnable: int | None = None,
                   env: dict[str, str] | None = None) -> int:
    """Threads for the next evaluation: ``$LETSPI_LLAMA_THREADS`` if set, else the usable CPUs not
    taken by other runnable tasks (``runnable`` counts this thread too), between 1 and ``max_threads``."""
    env = dict(os.environ) if env is None else env
    fixed = env.get(THREADS_ENV, "").strip()
    if fixed:
        try:
            return max(1, int(fixed))
        except ValueError:
            raise ValueError(f"${THREADS_ENV} must be a positive integer, got {fixed!r}") from None
    cpus = available_cpus() if cpus is None else cpus
    runnable = runnable_tasks() if runnable is None else runnable
    others = 0 if runnable is None else max(0, runnable - 1)
    return int(max(1, min(max_threads, cpus, cpus - others)))


# --- self-check --------------------------------------------------------------------------------


@dataclass(frozen=True)
class SelfCheckResult:
    """Batched vs token-by-token logits of ``CHECK_TEXT`` at ``positions`` (token counts). ``max_rel_diff``: max
    over positions of max|batched - sequential| / max|sequential|. ``verdict``: ``agree`` (argmax equal, within
    ``tolerance``), ``disagree`` or ``skipped``; ``mode``: how prompts are evaluated after the check."""

    verdict: Literal["agree", "disagree", "skipped"]
    mode: Literal["batched", "token-by-token"]
    max_rel_diff: float
    argmax_agree: bool
    tolerance: float
    positions: tuple[int, ...] = ()
    seconds: float = 0.0
    detail: str = ""

    def summary(self) -> str:
        if self.verdict == "skipped":
            return "self-check skipped"
        return (f"self-check {self.verdict}: batched vs token-by-token max relative logit difference "
                f"{self.max_rel_diff:.2e} (tolerance {self.tolerance:g}), argmax "
                f"{'equal' if self.argmax_agree else 'differs'} at {len(self.positions)} positions; prompts "
                f"evaluated {self.mode} ({self.seconds:.2f} s)")


def _last_logits(llm: Any) -> np.ndarray:
    n_vocab = int(llm.n_vocab())
    return np.ctypeslib.as_array(llm._ctx.get_logits(), shape=(n_vocab,)).astype(np.float64, copy=True)


def compare_logits(batched: np.ndarray, sequential: np.ndarray, tolerance: float) -> tuple[float, bool, bool]:
    """(max relative difference, argmax equal at every row, agree) for (P, V) logits of P positions."""
    scale = np.maximum(np.abs(sequential).max(axis=1), 1e-9)
    rel = float((np.abs(batched - sequential).max(axis=1) / scale).max())
    same = bool((batched.argmax(axis=1) == sequential.argmax(axis=1)).all())
    return rel, same, same and rel <= tolerance


def self_check(llm: Any, tolerance: float, text: str = CHECK_TEXT) -> SelfCheckResult:
    """Evaluate ``text`` in batches and token by token with the loaded ``llama_cpp.Llama`` and compare
    the logits at three positions (a third, two thirds and all of the prompt). Leaves the context reset."""
    t0 = time.perf_counter()
    tokens = list(llm.tokenize(text.encode("utf-8"), add_bos=True, special=False))
    n = len(tokens)
    positions = tuple(sorted({max(2, n // 3), max(2, 2 * n // 3), n}))
    sequential: list[np.ndarray] = []
    llm.reset()
    for i, tok in enumerate(tokens, start=1):
        llm.eval([tok])
        if i in positions:
            sequential.append(_last_logits(llm))
    batched: list[np.ndarray] = []
    for p in positions:
        llm.reset()
        llm.eval(tokens[:p])
        batched.append(_last_logits(llm))
    llm.reset()
    rel, same, ok = compare_logits(np.stack(batched), np.stack(sequential), tolerance)
    return SelfCheckResult("agree" if ok else "disagree", "batched", rel, same, tolerance, positions,
                           time.perf_counter() - t0)


# --- loading -----------------------------------------------------------------------------------


@dataclass
class LoadedLlama:
    """A shared ``Llama``, its lock (one generation at a time: the KV cache is shared state), and the
    self-check result that decided how its prompts are evaluated."""

    llm: Any
    lock: threading.Lock
    check: SelfCheckResult
    max_threads: int
    load_s: float = 0.0
    threads_used: list[int] = field(default_factory=list)

    def set_threads_for_call(self) -> int:
        n = choose_threads(self.max_threads)
        self.llm._ctx.set_n_threads(n, n)
        self.threads_used.append(n)
        return n


_INSTANCES: dict[tuple[str, str, int, int, LlamaRuntime], LoadedLlama] = {}
_INSTANCES_LOCK = threading.Lock()


def _load_checked(model_path: Path, *, n_ctx: int, n_threads: int, seed: int, lora_path: Path | None,
                  runtime: LlamaRuntime, tolerance: float) -> tuple[Any, SelfCheckResult]:
    llm = open_llama(model_path, n_ctx=n_ctx, n_threads=n_threads, seed=seed, lora_path=lora_path,
                     flash_attn=runtime.flash_attn)
    if runtime.self_check == "off":
        return llm, SelfCheckResult("skipped", "batched", float("nan"), True, tolerance)
    check = self_check(llm, tolerance)
    if check.verdict == "agree":
        return llm, check
    line = (f"llama.cpp self-check failed for {model_path.name}: batched prompt evaluation differs from "
            f"token-by-token (max relative logit difference {check.max_rel_diff:.2e} > {tolerance:g} or argmax "
            f"differs) with llama-cpp-python {llama_cpp_version()}")
    if runtime.self_check == "strict":
        llm.close()
        raise ModelSelfCheckError(f"{line}; refusing to plan with it (${SELF_CHECK_ENV}=strict). Try "
                                  f"${FLASH_ATTN_ENV}=1 or rebuild llama-cpp-python with "
                                  "CMAKE_ARGS=-DGGML_LLAMAFILE=OFF")
    llm.close()
    print(f"warning: {line}; evaluating prompts token by token (slower, correct)", file=sys.stderr)
    llm = open_llama(model_path, n_ctx=n_ctx, n_threads=n_threads, seed=seed, lora_path=lora_path,
                     flash_attn=runtime.flash_attn, token_by_token=True)
    return llm, SelfCheckResult("disagree", "token-by-token", check.max_rel_diff, check.argmax_agree, tolerance,
                                check.positions, check.seconds)


def shared_llama(model_path: Path, *, n_ctx: int = 4096, n_threads: int = DEFAULT_MAX_THREADS, seed: int = 0,
                 lora_path: Path | None = None, runtime: LlamaRuntime | None = None,
                 tolerance: float | None = None) -> LoadedLlama:
    """The process-wide model for this file (and LoRA adapter), loaded and self-checked on first use."""
    runtime = runtime or LlamaRuntime.from_env()
    key = (str(model_path), str(lora_path or ""), n_ctx, n_threads, runtime)
    with _INSTANCES_LOCK:
        hit = _INSTANCES.get(key)
        if hit is not None:
            return hit
        t0 = time.perf_counter()
        tol = batch_tolerance(model_path, lora_path) if tolerance is None else tolerance
        llm, check = _load_checked(model_path, n_ctx=n_ctx, n_threads=n_threads, seed=seed, lora_path=lora_path,
                                   runtime=runtime, tolerance=tol)
        # close before interpreter teardown: llama_cpp's __del__ fails noisily once its globals are gone
        atexit.register(llm.close)
        entry = LoadedLlama(llm, threading.Lock(), check, n_threads, time.perf_counter() - t0)
        _INSTANCES[key] = entry
        return entry


# --- the backend -------------------------------------------------------------------------------


class LlamaCppBackend:
    """``llamacpp:NAME`` (a packaged model) or ``llamacpp:/path/model.gguf``. ``lora_path``: a LoRA adapter
    GGUF (default: the fine-tuned model's own, ``locate_adapter``). ``n_threads``: the most a call uses."""

    def __init__(self, model: str, *, n_ctx: int = 4096, n_threads: int = DEFAULT_MAX_THREADS,
                 lora_path: Path | str | None = None, runtime: LlamaRuntime | None = None) -> None:
        self.model = model
        self.n_ctx = n_ctx
        self.n_threads = n_threads
        self.runtime = runtime or LlamaRuntime.from_env()
        import_llama_cpp()  # fail fast with the pip hint
        self.model_path = runnable_model(locate_model(model), flash_attn=self.runtime.flash_attn, n_threads=n_threads)
        self.lora_path = Path(lora_path) if lora_path is not None else locate_adapter(model)

    @property
    def spec(self) -> str:
        return f"llamacpp:{self.model}"

    @property
    def cache_identity(self) -> str:
        """What the response cache keys on beyond the spec: the weights (adapter included) and runtime."""
        adapter = file_fingerprint(self.lora_path) if self.lora_path is not None else "-"
        return f"{self.spec}|model={file_fingerprint(self.model_path)}|adapter={adapter}|{self.runtime.identity()}"

    def loaded(self, seed: int = 0) -> LoadedLlama:
        return shared_llama(self.model_path, n_ctx=self.n_ctx, n_threads=self.n_threads, seed=seed,
                            lora_path=self.lora_path, runtime=self.runtime)

    def load(self) -> None:
        """Load (and self-check) the model now (otherwise the first call does): callers time loading apart."""
        self.loaded()

    def complete(self, messages: Sequence[Message], *, schema: dict[str, Any] | None, settings: DecodingSettings,
                 timeout_s: float) -> LLMResponse:
        model = self.loaded(settings.seed)
        llm = model.llm
        response_format = {"type": "json_object", "schema": schema} if schema is not None else None
        with model.lock:  # one generation at a time per model: the KV cache is shared state
            model.set_threads_for_call()
            t0 = time.perf_counter()
            deadline = t0 + timeout_s
            parts: list[str] = []
            try:
                stream = llm.create_chat_completion(
                    messages=[dict(m) for m in messages], temperature=settings.temperature, seed=settings.seed,
                    max_tokens=settings.max_tokens, response_format=response_format, stream=True)
                for chunk in stream:
                    delta = chunk["choices"][0].get("delta", {})
                    text = delta.get("content")
                    if text:
                        parts.append(text)
                    if time.perf_counter() > deadline:
                        stream.close()
                        raise LLMTimeoutError(
                            f"{self.spec}: no complete reply within {timeout_s:.1f} s ({len(parts)} tokens)")
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
        return LLMResponse(text=text, parsed=try_parse_json(text), prompt_tokens=prompt_tokens,
                           completion_tokens=completion_tokens, latency_s=latency, model_spec=self.spec)
