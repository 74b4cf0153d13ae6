"""The embedded SmolLM2's file format: the packaged Q4_1 against the F16 (and Q8_0) copy planners load.

llama.cpp repacks Q4_0 and Q8_0 weights for its AVX2/AVX-512 kernels but has no such path for Q4_1, so
the packaged file evaluates prompts slowly; ``letspi.llm.models.runtime_copy`` converts it once. For each
format, in one process and in turn, this measures on the choice prompt of the standard scene (the
LoRA adapter applied, as ``letspi-fast`` asks it):

* ``prefill_s``: the whole prompt evaluated from an empty KV cache (median of ``repeats``);
* ``call_s``: one uncached ``{"option": NAME}`` call, schema-constrained and greedy, as the planner makes
  it (the system prompt's KV reused from the previous call, as it is in a run);
* ``ratio_*``: the packaged Q4_1 figure over this format's (> 1: faster);
* ``answers``: the greedy choices on ``scenes`` standard scenes (leader gap and speed varied), and how
  many agree with the packaged file's.

Every figure carries the 1-minute load average read before it.
"""

from __future__ import annotations

import os
import statistics
import time
from pathlib import Path
from typing import Any, Final

import numpy as np

from letspi.llm.backends.llamacpp import LlamaCppBackend
from letspi.llm.choice import OptionLine, choice_json_schema, parse_choice, render_choice_prompt
from letspi.llm.describe import describe_scenario
from letspi.llm.models import locate_adapter, packaged_smollm2_path, runtime_copy
from letspi.llm.types import DecodingSettings, Message
from letspi.scenario.build import VehicleSpec, straight_road_scenario

MODEL: Final = "smollm2-135m-letspi"
OPTION_NAMES: Final = ("default", "ease", "slow", "brake", "right-slow", "right-brake")


def scene_messages(gap_m: float, leader_speed_mps: float) -> list[Message]:
    """The choice prompt of a 3-lane scene: ego at 30 m/s, a leader ``gap_m`` ahead at ``leader_speed_mps``,
    a follower in the right lane; the default fails the leader-brakes future when the gap is short."""
    batch = straight_road_scenario(neighbours=[VehicleSpec(x0_m=gap_m, speed_mps=leader_speed_mps),
                                               VehicleSpec(x0_m=-25.0, speed_mps=31.0, lane_offset=1)],
                                   scenario_id="standard")
    short = gap_m < 25.0
    lines = [OptionLine("default", ("leader-brakes",) if short else (), 140.0),
             OptionLine("ease", ("leader-brakes",) if gap_m < 15.0 else (), 132.0),
             OptionLine("slow", (), 124.0), OptionLine("brake", (), 105.0),
             OptionLine("right-slow", ("follower-keeps",), 120.0),
             OptionLine("right-brake", ("follower-keeps",), 101.0)]
    risk = float(np.clip(1.0 - gap_m / 40.0, 0.01, 0.9))
    return render_choice_prompt(describe_scenario(batch, (150.0, 0.0)), lines, risk=risk)


def _measure(model_path: Path, scenes: list[list[Message]], repeats: int) -> dict[str, Any]:
    backend = LlamaCppBackend(MODEL, lora_path=locate_adapter(MODEL))
    backend.model_path = model_path  # the format under test, the adapter as shipped
    t0 = time.perf_counter()
    loaded = backend.loaded()
    load_s = time.perf_counter() - t0
    llm = loaded.llm
    schema = choice_json_schema(OPTION_NAMES)
    settings = DecodingSettings(max_tokens=16)
    first = scenes[0]
    backend.complete(first, schema=schema, settings=settings, timeout_s=600)  # warm-up (grammar, caches)
    tokens = llm.tokenize("".join(f"<|im_start|>{m['role']}\n{m['content']}<|im_end|>\n" for m in first).encode()
                          + b"<|im_start|>assistant\n", add_bos=False, special=True)
    prefill, calls, loads = [], [], []
    for _ in range(repeats):
        loads.append(os.getloadavg()[0])
        llm.reset()
        t = time.perf_counter()
        llm.eval(tokens)
        prefill.append(time.perf_counter() - t)
        backend.complete(scenes[-1], schema=schema, settings=settings, timeout_s=600)  # another scene's prompt
        r = backend.complete(first, schema=schema, settings=settings, timeout_s=600)  # system prefix reused
        calls.append(r.latency_s)
    answers = [parse_choice(backend.complete(m, schema=schema, settings=settings, timeout_s=600).text, OPTION_NAMES)
               for m in scenes]
    return {"file": model_path.name, "bytes": model_path.stat().st_size, "load_s": load_s,
            "prompt_tokens": len(tokens), "prefill_s": statistics.median(prefill),
            "tokens_per_s": len(tokens) / statistics.median(prefill), "call_s": statistics.median(calls),
            "self_check": loaded.check.summary(), "loadavg_1min": loads, "answers": answers}


def bench_formats(repeats: int = 5, scenes: int = 12, formats: tuple[str, ...] = ("F16", "Q8_0")) -> dict[str, Any]:
    """Per format (the packaged Q4_1 first): prefill, call latency, ratios and greedy agreement (docstring)."""
    gaps = np.linspace(8.0, 60.0, scenes)
    messages = [scene_messages(float(g), 30.0 - 8.0 * (i % 3)) for i, g in enumerate(gaps)]
    source = packaged_smollm2_path()
    result: dict[str, Any] = {"model": MODEL, "repeats": repeats, "scenes": scenes, "cpus": os.cpu_count(),
                              "loadavg_start": list(os.getloadavg())}
    reference = _measure(source, messages, repeats)
    result["Q4_1 (packaged)"] = reference
    for fmt in formats:
        row = _measure(runtime_copy(source, fmt), messages, repeats)
        row["ratio_prefill"] = reference["prefill_s"] / row["prefill_s"]
        row["ratio_call"] = reference["call_s"] / row["call_s"]
        row["answers_agree"] = sum(a == b for a, b in zip(row["answers"], reference["answers"], strict=True))
        result[fmt] = row
    result["loadavg_end"] = list(os.getloadavg())
    return result
