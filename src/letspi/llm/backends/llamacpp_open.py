"""The one way into llama.cpp: every model letspi runs is opened by ``open_llama``.

* AMX workaround (docs/llm.md): where the build has AMX kernels, models load with ``use_extra_bufts = False``;
  ``LETSPI_LLAMA_EXTRA_BUFTS=1``/``0`` forces it.
* Probe: the first load of each (build, CPU flags, format, settings) runs in a child process
  (``python -m letspi.llm.backends.llamacpp_open probe MODEL.gguf``), so a fault cannot kill the caller: a
  quantized file falls back to its F16 copy, anything else raises ``LlamaFaultError``. Verdicts are cached
  in ``$LETSPI_CACHE_DIR/llama_probes/``; ``LETSPI_LLAMA_PROBE=0`` skips the probe.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from importlib import metadata
from pathlib import Path
from typing import Any, Final, Literal

from letspi.fsutil import atomic_write_text
from letspi.llm.cache import default_cache_dir
from letspi.llm.gguf_info import GGUFHeaderError, is_float_format, model_format
from letspi.llm.models import runtime_copy
from letspi.llm.types import LlamaFaultError, MissingDependencyError

INSTALL_HINT: Final = (
    "the llamacpp backend needs llama-cpp-python: pip install llama-cpp-python "
    "(builds from source, about 6 min on 2 cores)"
)
PROBE_ENV: Final = "LETSPI_LLAMA_PROBE"
EXTRA_BUFTS_ENV: Final = "LETSPI_LLAMA_EXTRA_BUFTS"
#: libgomp spin iterations (~0.1 ms) before a waiting OpenMP worker sleeps (notes/embedded_model.md)
OMP_SPIN_COUNT: Final = 100_000
PROBE_TIMEOUT_S: Final = 300.0
PROBE_TEXT: Final = "A car drives at 30 m/s on a highway. The car ahead is 20 m away and brakes hard, so the driver"
LLAMA_PIN: Final = "llama-cpp-python==0.3.36"


def llama_cpp_version() -> str:
    try:
        return metadata.version("llama-cpp-python")
    except metadata.PackageNotFoundError:
        return "absent"


def import_llama_cpp() -> Any:
    """``llama_cpp``, imported with letspi's OpenMP settings (waiting workers spin briefly, then sleep)."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    os.environ.setdefault("GOMP_SPINCOUNT", str(OMP_SPIN_COUNT))
    try:
        import llama_cpp
        import llama_cpp.llama
    except ImportError as exc:
        raise MissingDependencyError(f"{INSTALL_HINT} ({exc})") from None
    return llama_cpp


def system_info(llama_mod: Any) -> str:
    """llama.cpp's ``system_info`` line (the instruction sets the build uses), '' if unavailable."""
    try:
        info = llama_mod.llama_print_system_info()
    except (AttributeError, OSError):
        return ""
    return info.decode(errors="replace") if isinstance(info, bytes) else str(info)


def amx_compiled_in(llama_mod: Any) -> bool:
    """Whether the loaded llama.cpp CPU backend was built with AMX kernels."""
    text = system_info(llama_mod)
    return "AMX_INT8 = 1" in text or "AMX_TILE = 1" in text or "AMX_BF16 = 1" in text


def extra_buffer_types_disabled(llama_mod: Any) -> bool:
    """The AMX workaround's decision (module docstring)."""
    setting = os.environ.get(EXTRA_BUFTS_ENV, "auto")
    if setting in ("0", "1"):
        return setting == "0"
    return amx_compiled_in(llama_mod)


@contextmanager
def without_extra_buffer_types(llama_mod: Any) -> Iterator[None]:
    """Make ``Llama(...)`` load with ``use_extra_bufts = False`` where the workaround applies."""
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


def _construct(model_path: Path, **kwargs: Any) -> Any:
    llama_mod = import_llama_cpp()
    with without_extra_buffer_types(llama_mod):
        return llama_mod.Llama(model_path=str(model_path), verbose=False, **kwargs)


# --- what identifies a probe -------------------------------------------------------------------


def _cpuinfo(key: str) -> str | None:
    """The value of the first ``/proc/cpuinfo`` line starting with ``key`` (None where there is none)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            return next((line.split(":", 1)[1] for line in fh if line.startswith(key)), None)
    except OSError:
        return None


def cpu_flags() -> frozenset[str]:
    """The CPU's feature flags (``/proc/cpuinfo``; empty where it cannot be read)."""
    return frozenset((_cpuinfo("flags") or "").split())


def cpu_name() -> str:
    name = _cpuinfo("model name")
    return "this CPU" if name is None else name.strip()


def build_identity() -> str:
    """llama-cpp-python's version and a digest of its shared libraries' names, sizes and times (not imported)."""
    h = hashlib.sha256()
    spec = importlib.util.find_spec("llama_cpp")
    if spec is not None and spec.submodule_search_locations:
        lib = Path(next(iter(spec.submodule_search_locations))) / "lib"
        for f in sorted(lib.glob("*")) if lib.is_dir() else []:
            if f.is_file() and not f.is_symlink():
                st = f.stat()
                h.update(f"{f.name}:{st.st_size}:{st.st_mtime_ns};".encode())
    return f"{llama_cpp_version()}:{h.hexdigest()[:16]}"


def probe_key(fmt: str, flash_attn: bool, n_threads: int) -> dict[str, Any]:
    """Everything a probe's verdict depends on."""
    return {"build": build_identity(), "cpu_flags": hashlib.sha256(" ".join(sorted(cpu_flags())).encode()).hexdigest(),
            "format": fmt, "flash_attn": bool(flash_attn), "n_threads": int(n_threads),
            "extra_bufts": os.environ.get(EXTRA_BUFTS_ENV, "auto")}


# --- the probe ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class ProbeResult:
    """``verdict``: ``ok``; ``fault`` (the child was killed by ``signal_name``); ``error`` (it raised: the real
    load reports it); ``timeout``. ``system_info``: the build's line, if printed before failing."""

    verdict: Literal["ok", "fault", "error", "timeout"]
    signal_name: str = ""
    system_info: str = ""
    detail: str = ""
    seconds: float = 0.0


ProbeRunner = Callable[[Sequence[str], float], ProbeResult]


def probe_command(model_path: Path, flash_attn: bool, n_threads: int) -> list[str]:
    return [sys.executable, "-m", "letspi.llm.backends.llamacpp_open", "probe", str(model_path),
            "--flash-attn", str(int(flash_attn)), "--threads", str(n_threads)]


def run_probe(command: Sequence[str], timeout_s: float = PROBE_TIMEOUT_S) -> ProbeResult:
    """Run a probe ``command`` in a child process and classify how it ended."""
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(list(command), capture_output=True, text=True, timeout=timeout_s, check=False)
    except subprocess.TimeoutExpired:
        return ProbeResult("timeout", detail=f"no verdict within {timeout_s:.0f} s", seconds=timeout_s)
    seconds = time.perf_counter() - t0
    info = next((line.split(":", 1)[1].strip() for line in proc.stdout.splitlines()
                 if line.startswith("system_info:")), "")
    if proc.returncode < 0:
        try:
            name = signal.Signals(-proc.returncode).name
        except ValueError:
            name = f"signal {-proc.returncode}"
        return ProbeResult("fault", name, info, proc.stderr.strip()[-500:], seconds)
    if proc.returncode == 0 and proc.stdout.rstrip().endswith("ok"):
        return ProbeResult("ok", system_info=info, seconds=seconds)
    return ProbeResult("error", system_info=info, detail=proc.stderr.strip()[-500:], seconds=seconds)


#: llama.cpp system_info names -> /proc/cpuinfo flags
BUILD_FEATURES: Final[dict[str, str]] = {
    "AVX": "avx", "AVX2": "avx2", "FMA": "fma", "F16C": "f16c", "AVX512": "avx512f", "AVX512_VBMI": "avx512_vbmi",
    "AVX512_VNNI": "avx512_vnni", "AVX512_BF16": "avx512_bf16", "AVX_VNNI": "avx_vnni", "AMX_INT8": "amx_int8",
    "AMX_TILE": "amx_tile", "AMX_BF16": "amx_bf16",
}
PORTABLE_CMAKE_ARGS: Final = ("-DGGML_NATIVE=OFF -DGGML_AMX_TILE=OFF -DGGML_AMX_INT8=OFF -DGGML_AMX_BF16=OFF "
                              "-DGGML_AVX512=OFF -DGGML_AVX2=ON -DGGML_FMA=ON -DGGML_F16C=ON")


def build_features(info: str) -> set[str]:
    """The instruction-set features a ``system_info`` line says the build uses (``AVX2 = 1`` -> ``AVX2``)."""
    out: set[str] = set()
    for field in info.replace("|", "\n").splitlines():
        name, _, value = field.partition("=")
        if value.strip() == "1" and name.strip() in BUILD_FEATURES:
            out.add(name.strip())
    return out


def fault_cause(info: str, flags: frozenset[str]) -> str:
    """The CPU feature to blame for a fault: one the build uses and the CPU lacks, else AMX where both have it."""
    used = build_features(info)
    missing = sorted(f for f in used if BUILD_FEATURES[f] not in flags) if flags else []
    if missing:
        return (f"this llama.cpp build uses {', '.join(missing)}, which this CPU lacks (a wheel built on "
                "another machine?)")
    if used & {"AMX_INT8", "AMX_TILE", "AMX_BF16"}:
        return "AMX: this CPU advertises AMX tiles but faults on them (a VM that does not enable AMX state)"
    return "an instruction this CPU or VM does not run"


def fault_line(model_path: Path, fmt: str, result: ProbeResult, flags: frozenset[str]) -> str:
    """The one line a faulting model ends in: format, signal, CPU feature, what to do."""
    return (f"llama.cpp crashes ({result.signal_name}) running the {fmt} model {model_path.name} on {cpu_name()}: "
            f"{fault_cause(result.system_info, flags)}. Use an F16 file, or rebuild llama.cpp for this CPU: "
            f'CMAKE_ARGS="{PORTABLE_CMAKE_ARGS}" pip install --force-reinstall --no-cache-dir {LLAMA_PIN}')


def _cache_file(key: dict[str, Any]) -> Path:
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:20]
    return default_cache_dir() / "llama_probes" / f"{digest}.json"


def probe_verdict(model_path: Path, fmt: str, *, flash_attn: bool, n_threads: int,
                  runner: ProbeRunner = run_probe) -> ProbeResult:
    """The cached verdict for this (build, CPU, format, settings), probing ``model_path`` when there is none.
    Only ``ok`` and ``fault`` are cached (an error or a timeout says nothing about the CPU)."""
    key = probe_key(fmt, flash_attn, n_threads)
    cache = _cache_file(key)
    try:
        return ProbeResult(**json.loads(cache.read_text())["result"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    result = runner(probe_command(model_path, flash_attn, n_threads), PROBE_TIMEOUT_S)
    if result.verdict in ("ok", "fault"):
        try:
            cache.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(cache, json.dumps({"key": key, "model": model_path.name,
                                                 "result": asdict(result)}, indent=2) + "\n")
        except OSError:  # an unwritable cache only costs a probe next time
            pass
    return result


_RUNNABLE: dict[tuple[str, bool, int, bool], Path] = {}
_RUNNABLE_LOCK = threading.Lock()


def runnable_model(model_path: Path, *, flash_attn: bool = True, n_threads: int = 2, fallback: bool = True,
                   runner: ProbeRunner = run_probe) -> Path:
    """``model_path``, or its F16 copy where its quantized kernels fault here (one warning).
    Raises ``LlamaFaultError`` where nothing runs."""
    model_path = Path(model_path)
    if os.environ.get(PROBE_ENV, "1").strip() == "0":
        return model_path
    memo = (str(model_path), bool(flash_attn), int(n_threads), fallback)
    with _RUNNABLE_LOCK:
        if memo in _RUNNABLE:
            return _RUNNABLE[memo]
        try:
            fmt = model_format(model_path)
        except (GGUFHeaderError, OSError):  # nothing to probe: llama.cpp's own load reports the file
            return model_path
        result = probe_verdict(model_path, fmt, flash_attn=flash_attn, n_threads=n_threads, runner=runner)
        chosen = model_path
        if result.verdict == "timeout":
            print(f"warning: the llama.cpp probe of {model_path.name} gave no verdict within {PROBE_TIMEOUT_S:.0f} s; "
                  "loading it unprobed", file=sys.stderr)
        elif result.verdict == "fault":
            line = fault_line(model_path, fmt, result, cpu_flags())
            if not fallback or is_float_format(fmt):
                raise LlamaFaultError(line)
            copy = runtime_copy(model_path, "F16")
            again = probe_verdict(copy, model_format(copy), flash_attn=flash_attn, n_threads=n_threads, runner=runner)
            if again.verdict == "fault":
                raise LlamaFaultError(line)
            print(f"warning: {line.split(': ', 1)[0]}; running its F16 copy {copy.name} instead (the same weights, "
                  f"dequantized; {fault_cause(result.system_info, cpu_flags())})", file=sys.stderr)
            chosen = copy
        _RUNNABLE[memo] = chosen
        return chosen


def open_llama(model_path: Path, *, n_ctx: int, n_threads: int, seed: int = 0, lora_path: Path | None = None,
               flash_attn: bool = True, token_by_token: bool = False, logits_all: bool = False,
               fallback: bool = True) -> Any:
    """A ``llama_cpp.Llama`` of the runnable form of ``model_path`` (probed, AMX workaround applied).
    ``fallback=False``: a faulting quantized file raises ``LlamaFaultError`` instead of running its F16 copy."""
    path = runnable_model(model_path, flash_attn=flash_attn, n_threads=n_threads, fallback=fallback)
    n_batch = 1 if token_by_token else 512
    return _construct(path, n_ctx=n_ctx, n_threads=n_threads, n_threads_batch=n_threads, n_batch=n_batch,
                      n_ubatch=n_batch, seed=seed, flash_attn=flash_attn, logits_all=logits_all,
                      lora_path=str(lora_path) if lora_path is not None else None)


def open_vocab(model_path: Path) -> Any:
    """A ``llama_cpp.Llama`` holding only ``model_path``'s tokenizer (no weights, no kernels: not probed)."""
    return _construct(Path(model_path), vocab_only=True)


# --- the child process -------------------------------------------------------------------------


def _probe_child(model_path: Path, flash_attn: bool, n_threads: int) -> None:
    llama_mod = import_llama_cpp()
    print(f"system_info: {system_info(llama_mod)}", flush=True)
    llm = _construct(model_path, n_ctx=256, n_threads=n_threads, n_threads_batch=n_threads, n_batch=512,
                     n_ubatch=512, flash_attn=flash_attn)
    tokens = list(llm.tokenize(PROBE_TEXT.encode(), add_bos=True, special=False))
    llm.eval(tokens)  # one batch: the matrix kernels a prompt uses
    llm.reset()
    for tok in tokens[:3]:  # one token at a time: the kernels generation uses
        llm.eval([tok])
    llm.close()
    print("ok", flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m letspi.llm.backends.llamacpp_open")
    sub = parser.add_subparsers(dest="command", required=True)
    probe = sub.add_parser("probe", help="load MODEL and evaluate a short prompt (run in a child process)")
    probe.add_argument("model", type=Path)
    probe.add_argument("--flash-attn", type=int, default=1)
    probe.add_argument("--threads", type=int, default=2)
    args = parser.parse_args(argv)
    _probe_child(args.model, bool(args.flash_attn), args.threads)
    return 0


if __name__ == "__main__":
    sys.exit(main())
