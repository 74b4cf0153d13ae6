"""Real models: embedded llama.cpp and llama-cpp-python's OpenAI-compatible server.

Skipped when llama-cpp-python, the model packages or the server extras are missing. Each
test takes about 5-15 s on 2 cores: marked slow (``pytest -m slow``; CI runs them after the default
suite). The default suite covers the backend's parsing, spec and cache code without a model.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from letspi.llm.client import ParamAdvisor
from letspi.llm.describe import describe_scenario
from letspi.llm.models import locate_model
from letspi.llm.prompts import render_fast_prompt
from letspi.llm.schema import FIELD_RANGES
from letspi.llm.types import DecodingSettings, MissingDependencyError, message
from letspi.scenario.build import VehicleSpec, straight_road_scenario

pytestmark = pytest.mark.slow
llama_cpp = pytest.importorskip("llama_cpp")


def _model(name: str) -> Path:
    try:
        return locate_model(name)
    except MissingDependencyError as exc:
        pytest.skip(str(exc))


@pytest.fixture(scope="module")
def fast_messages() -> list:
    scn = straight_road_scenario(neighbours=[VehicleSpec(x0_m=20.0, speed_mps=22.0)])
    return render_fast_prompt(describe_scenario(scn, (150.0, 0.0)))


def _in_range(reply: object) -> None:
    for name, (lo, hi) in FIELD_RANGES.items():
        assert lo <= getattr(reply, name) <= hi


def test_smollm2_schema_constrained_reply(fast_messages: list, tmp_path: Path) -> None:
    _model("smollm2-135m")
    adv = ParamAdvisor("llamacpp:smollm2-135m", cache=None, settings=DecodingSettings(max_tokens=120))
    a = adv.advise(fast_messages, variant="fast")
    assert a.attempts[-1].text and a.response is not None
    # Grammar-constrained: the text itself is the schema's JSON object.
    assert a.response.parsed is not None and set(a.response.parsed) == {
        "tau",
        "k_np",
        "k_nf",
        "k_nl",
        "k_bd",
        "k_cl",
        "lon",
        "lane",
    }
    assert not a.fallback
    _in_range(a.reply)
    assert a.prompt_tokens > 100 and 0 < a.completion_tokens <= 120


def test_gemma_reply_and_cache_hit(fast_messages: list, tmp_path: Path) -> None:
    _model("gemma3-270m")
    from letspi.llm.cache import ResponseCache

    cache = ResponseCache(tmp_path / "c.sqlite")
    adv = ParamAdvisor("llamacpp:gemma3-270m", cache=cache, settings=DecodingSettings(max_tokens=120))
    a = adv.advise(fast_messages, variant="fast")
    assert not a.fallback
    _in_range(a.reply)
    t0 = time.perf_counter()
    b = adv.advise(fast_messages, variant="fast")
    assert b.cached and b.reply == a.reply and time.perf_counter() - t0 < 0.5


def test_embedded_timeout_is_enforced() -> None:
    _model("smollm2-135m")
    from letspi.llm.backends.llamacpp import LlamaCppBackend
    from letspi.llm.types import LLMTimeoutError

    be = LlamaCppBackend("smollm2-135m")
    with pytest.raises(LLMTimeoutError):
        be.complete(
            [message("user", "Count from 1 to 500.")],
            schema=None,
            settings=DecodingSettings(max_tokens=400),
            timeout_s=0.3,
        )


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])




@pytest.fixture(scope="module")
def llama_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    pytest.importorskip("uvicorn")
    pytest.importorskip("sse_starlette")
    pytest.importorskip("starlette_context")
    pytest.importorskip("pydantic_settings")
    model = _model("smollm2-135m")
    port = _free_port()
    cmd = [
        sys.executable,
        "-m",
        "letspi.llm.backends.llamacpp_server",
        "--model",
        str(model),
        "--host",
        "127.0.0.1",
        "--port",
        str(port),
        "--n_ctx",
        "2048",
        "--n_threads",
        "2",
        "--model_alias",
        "smollm2",
    ]
    log_path = tmp_path_factory.mktemp("llama_server") / "server.log"
    log = log_path.open("wb")  # a file, not a pipe: llama.cpp's load log would fill a pipe and block
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env={**os.environ})
    url = f"http://127.0.0.1:{port}/v1"
    try:
        deadline = time.monotonic() + 90
        while True:
            if proc.poll() is not None:
                err = log_path.read_text(errors="replace")[-2000:]
                pytest.fail(f"llama_cpp.server exited with {proc.returncode}: {err}")
            try:
                if httpx.get(f"{url}/models", timeout=1.0).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > deadline:
                pytest.fail("llama_cpp.server did not start within 90 s")
            time.sleep(0.3)
        yield url
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
        log.close()


def test_openai_client_against_llama_cpp_server(llama_server: str, fast_messages: list) -> None:
    from letspi.llm.backends.openai_compat import OpenAICompatBackend

    # llama-cpp-python's server constrains decoding with {"type": "json_object", "schema": ...};
    # it accepts {"type": "json_schema"} but ignores it.
    be = OpenAICompatBackend("smollm2", base_url=llama_server, api_key="", format_mode="json_object_schema")
    adv = ParamAdvisor(be, cache=None, settings=DecodingSettings(max_tokens=120))
    a = adv.advise(fast_messages, variant="fast")
    assert not a.fallback and a.response is not None and a.response.prompt_tokens > 100
    assert a.response.parsed is not None and set(a.response.parsed) == {
        "tau",
        "k_np",
        "k_nf",
        "k_nl",
        "k_bd",
        "k_cl",
        "lon",
        "lane",
    }
    _in_range(a.reply)
    # auto mode also ends with a usable reply (whichever format the server honours)
    auto = ParamAdvisor(
        OpenAICompatBackend("smollm2", base_url=llama_server, api_key=""),
        cache=None,
        settings=DecodingSettings(max_tokens=120),
    )
    b = auto.advise(fast_messages, variant="fast")
    assert b.response is not None and b.response.completion_tokens > 0
