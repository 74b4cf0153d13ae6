"""The ``openai:`` backend against a real OpenAI-compatible server: llama-cpp-python's
(``python -m llama_cpp.server``) serving the embedded SmolLM2, started on a free port.

Slow (the model answers in seconds to tens of seconds on a loaded 2-core machine); skipped with the
reason when the server extra (``pip install "llama-cpp-python[server]"``) or the model is missing.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest

from benchmarks.llm_concurrency import prefix_reuse, real_server_available, start_llama_server
from letspi.assembly.planners import build_planners
from letspi.evaluation.harness import EvaluationSettings, evaluate
from letspi.evaluation.results import load_planner_results
from letspi.llm.backends.openai_compat import OpenAICompatBackend
from letspi.llm.client import ParamAdvisor, RetryPolicy
from letspi.llm.latency import bench_scenarios
from letspi.llm.prompts import render_fast_prompt
from letspi.llm.schema import reply_json_schema
from letspi.planners.options import PlannerOptions
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import concat_batches

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def llama_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, Path]]:
    why = real_server_available()
    if why is not None:
        pytest.skip(why)
    log = tmp_path_factory.mktemp("llama-server") / "server.log"
    server, url = start_llama_server(log)
    try:
        yield url, log
    finally:
        server.close()


def test_schema_constrained_reply_through_the_openai_backend(llama_server: tuple[str, Path]) -> None:
    url, _ = llama_server
    backend = OpenAICompatBackend("smollm2", base_url=url)
    advisor = ParamAdvisor(backend, cache=None, retry=RetryPolicy(max_attempts=2, timeout_s=600.0))
    advice = advisor.advise(render_fast_prompt(bench_scenarios()["close_leader"]), variant="fast")
    assert advice.response is not None and not advice.fallback
    # llama-cpp-python's server takes the schema as {"type": "json_object", "schema": ...}
    assert advice.response.extra["format_mode"] in ("json_schema", "json_object_schema")
    reply = json.loads(advice.response.text)  # grammar-constrained: one JSON object, nothing else
    assert set(reply) == set(reply_json_schema("fast")["properties"])
    assert advice.prompt_tokens > 300 and advice.completion_tokens > 10


def test_concurrent_evaluation_against_the_real_server(llama_server: tuple[str, Path], tmp_path: Path) -> None:
    url, log = llama_server
    before = len(log.read_text(errors="replace"))
    batch = concat_batches([straight_road_scenario(scenario_id=f"real{i}", ego_speed_mps=26.0 + 2 * i,
                                                   neighbours=[VehicleSpec(x0_m=20.0 + 10 * i, speed_mps=24.0)])
                            for i in range(3)])
    spec = f"openai:smollm2@{url}"
    options = PlannerOptions(llm=spec, goals="kinematic", max_iterations=0, llm_cache=False)
    planners = build_planners(["llm"], options)
    planners[0].planner.advisor.retry = RetryPolicy(max_attempts=2, timeout_s=600.0)  # type: ignore[attr-defined]
    runs = {}
    evaluate(planners, batch, tmp_path / "eval", EvaluationSettings(concurrency=2, on_run=runs.__setitem__))
    rows = load_planner_results(tmp_path / "eval", "llm")
    assert len(rows) == 3 and runs["llm"].written == 3 and runs["llm"].failed == 0
    assert runs["llm"].requests is not None and runs["llm"].requests.requests >= 3
    reuse = prefix_reuse(log.read_text(errors="replace")[before:])
    # every request after the first reuses at least the static system prompt from the previous one
    assert reuse["requests_with_prefix_hit"] >= 2 and reuse["prompt_tokens_reused"] >= 2 * 300
