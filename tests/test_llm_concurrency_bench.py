"""``python -m benchmarks.speed llm --concurrency``: the numbers it prints come from real requests and add up."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from benchmarks.llm_concurrency import prefix_reuse
from benchmarks.speed import app as speed_app


def test_bench_concurrency_json_reports_scenarios_per_s_per_level() -> None:
    result = CliRunner().invoke(speed_app, ["llm", "--concurrency", "1,4", "--server-latency-ms", "50",
                                      "--no-pipeline", "--no-real-server", "--json"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    levels = out["concurrency"]
    assert set(levels) == {"1", "4"} and out["server_latency_ms"] == 50.0
    one, four = levels["1"], levels["4"]
    # one request at a time cannot beat the server's latency; four in flight must overlap them
    assert one["scenarios_per_s"] < 1 / one["injected_latency_mean_s"]
    assert four["scenarios_per_s"] > 1 / four["injected_latency_mean_s"]
    assert out["ratios"]["4_over_1"] > 2.5 and one["fallbacks"] == four["fallbacks"] == 0
    assert one["client_overhead_ms_per_request"] >= 0 and one["client_cpu_ms_per_request"] > 0
    assert out["targets"]["measured"]["client_overhead_ms"] == one["client_overhead_ms_per_request"]


def test_prefix_reuse_reads_the_llama_cpp_server_log() -> None:
    log = ("Llama.generate: 360 prefix-match hit, remaining 342 prompt tokens to eval\nnoise\n"
           "Llama.generate: 700 prefix-match hit, remaining 40 prompt tokens to eval\n")
    got = prefix_reuse(log)
    assert got["requests_with_prefix_hit"] == 2 and got["prompt_tokens_reused"] == 1060
    assert got["prompt_tokens_evaluated"] == 382 and got["reused_fraction"] == round(1060 / 1442, 3)
