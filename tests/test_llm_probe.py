"""The probe that runs a model's first load in a child process (``letspi.llm.backends.llamacpp_open``)."""

from __future__ import annotations

import ast
import sys
from collections.abc import Sequence
from pathlib import Path

import pytest

from letspi.llm.backends import llamacpp_open
from letspi.llm.backends.llamacpp_open import (
    PROBE_ENV,
    ProbeResult,
    fault_cause,
    fault_line,
    run_probe,
    runnable_model,
)
from letspi.llm.gguf_info import GGUFHeaderError, model_format, tensor_types
from letspi.llm.models import packaged_smollm2_path
from letspi.llm.types import LlamaFaultError

REPO = Path(__file__).resolve().parents[1]
AVX512_BUILD = "CPU : SSE3 = 1 | AVX = 1 | AVX2 = 1 | F16C = 1 | FMA = 1 | AVX512 = 1 | AMX_INT8 = 0 | OPENMP = 1 |"
AMX_BUILD = "CPU : SSE3 = 1 | AVX2 = 1 | AVX512 = 1 | AMX_INT8 = 1 | OPENMP = 1 |"


def _child(code: str) -> list[str]:
    return [sys.executable, "-c", code]


def test_a_child_killed_by_sigill_is_a_fault_with_the_builds_line() -> None:
    result = run_probe(_child("import os, signal; print('system_info: " + AVX512_BUILD + "', flush=True); "
                              "os.kill(os.getpid(), signal.SIGILL)"), 60)
    assert result.verdict == "fault" and result.signal_name == "SIGILL"
    assert result.system_info == AVX512_BUILD


def test_a_child_that_prints_ok_passes_and_one_that_raises_is_an_error_not_a_fault() -> None:
    assert run_probe(_child("print('system_info: x'); print('ok')"), 60).verdict == "ok"
    err = run_probe(_child("raise SystemExit('not a model')"), 60)
    assert err.verdict == "error" and "not a model" in err.detail
    assert run_probe(_child("import time; time.sleep(30)"), 0.5).verdict == "timeout"


def test_the_cause_names_the_feature_the_cpu_lacks_else_amx() -> None:
    zen3 = frozenset({"sse3", "avx", "avx2", "fma", "f16c"})
    assert "uses AVX512, which this CPU lacks" in fault_cause(AVX512_BUILD, zen3)
    sapphire = zen3 | {"avx512f", "amx_int8", "amx_tile"}
    assert fault_cause(AMX_BUILD, sapphire).startswith("AMX")
    line = fault_line(Path("m.gguf"), "Q4_0", ProbeResult("fault", "SIGILL", AMX_BUILD), sapphire)
    assert line.startswith("llama.cpp crashes (SIGILL) running the Q4_0 model m.gguf")
    assert 'CMAKE_ARGS="-DGGML_NATIVE=OFF' in line and "--no-cache-dir llama-cpp-python==" in line


@pytest.fixture
def packaged(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    pytest.importorskip("llama_cpp")
    monkeypatch.setenv("LETSPI_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv(PROBE_ENV, raising=False)
    monkeypatch.setattr(llamacpp_open, "_RUNNABLE", {})
    try:
        return packaged_smollm2_path()
    except Exception as exc:  # the model package is optional in some environments
        pytest.skip(str(exc))


def _faulting_on_quantized(calls: list[str]) -> llamacpp_open.ProbeRunner:
    """A probe runner whose child faults on quantized files (as llama.cpp's AMX kernels do in some VMs)."""

    def runner(command: Sequence[str], timeout_s: float) -> ProbeResult:
        model = Path(command[command.index("probe") + 1])
        calls.append(model_format(model))
        sigill = f"print('system_info: {AMX_BUILD}', flush=True); os.kill(os.getpid(), signal.SIGILL)"
        code = "print('ok')" if model_format(model) == "F16" else f"import os, signal; {sigill}"
        return run_probe(_child(code), timeout_s)

    return runner


def test_a_faulting_quantized_file_runs_as_its_f16_copy_with_one_warning_and_the_verdicts_are_cached(
        packaged: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[str] = []
    chosen = runnable_model(packaged, runner=_faulting_on_quantized(calls))
    assert chosen != packaged and model_format(chosen) == "F16" and calls == ["Q4_1+Q8_0", "F16"]
    err = capsys.readouterr().err
    assert err.count("warning:") == 1 and "SIGILL" in err and "Q4_1+Q8_0" in err and "F16 copy" in err
    assert runnable_model(packaged, runner=_faulting_on_quantized(calls)) == chosen and len(calls) == 2
    monkeypatch.setattr(llamacpp_open, "_RUNNABLE", {})  # a new process: the verdicts come from the cache
    assert runnable_model(packaged, runner=_faulting_on_quantized(calls)) == chosen and len(calls) == 2
    with pytest.raises(LlamaFaultError, match=r"crashes \(SIGILL\) running the Q4_1\+Q8_0 model"):
        runnable_model(packaged, fallback=False, runner=_faulting_on_quantized(calls))


def test_a_faulting_float_file_stops_with_one_line(packaged: Path, tmp_path: Path) -> None:
    def runner(command: Sequence[str], timeout_s: float) -> ProbeResult:
        return run_probe(_child("import os, signal; os.kill(os.getpid(), signal.SIGSEGV)"), timeout_s)

    f16 = llamacpp_open.runtime_copy(packaged, "F16", cache_dir=tmp_path)
    with pytest.raises(LlamaFaultError, match=r"crashes \(SIGSEGV\) running the F16 model .*pip install"):
        runnable_model(f16, runner=runner)


def test_the_real_probe_runs_the_packaged_file_here(packaged: Path) -> None:
    result = llamacpp_open.probe_verdict(packaged, model_format(packaged), flash_attn=True, n_threads=2)
    assert result.verdict == "ok", result
    assert "AVX" in result.system_info  # the build's line came back from the child


def test_the_header_reader_counts_the_packaged_files_tensors(packaged: Path, tmp_path: Path) -> None:
    counts = tensor_types(packaged)
    assert counts["Q4_1"] > 100 and counts["F32"] > 0 and sum(counts.values()) == 272
    bad = tmp_path / "x.gguf"
    bad.write_bytes(b"GGML" + b"\0" * 20)
    with pytest.raises(GGUFHeaderError, match="x.gguf: not a GGUF file"):
        tensor_types(bad)
    bad.write_bytes(packaged.read_bytes()[:5000])
    with pytest.raises(GGUFHeaderError, match="truncated"):
        tensor_types(bad)


def _llama_calls(path: Path) -> list[int]:
    """Lines of ``path`` that construct ``Llama`` (``Llama(...)``, ``llama_cpp.Llama(...)``) or run
    llama-cpp-python's server module directly."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
            if name == "Llama":
                lines.append(node.lineno)
        if isinstance(node, ast.Constant) and node.value == "llama_cpp.server":
            lines.append(node.lineno)
    return lines


def test_every_model_load_goes_through_letspis_loader() -> None:
    allowed = {REPO / "src/letspi/llm/backends/llamacpp_open.py", REPO / "src/letspi/llm/backends/llamacpp_server.py",
               Path(__file__).resolve()}
    found = []
    for folder in ("src", "tests", "scripts", "benchmarks", "examples"):
        for path in sorted((REPO / folder).rglob("*.py")):
            if path not in allowed:
                found += [f"{path.relative_to(REPO)}:{line}" for line in _llama_calls(path)]
    assert not found, f"open llama.cpp models with letspi.llm.backends.llamacpp_open.open_llama: {found}"
