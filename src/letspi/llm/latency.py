"""Latency and behaviour of LLM specs on hand-built scenes (``letspi llm bench``, ``letspi llm check``).

``bench_models()`` measures, per embedded model, the physics and fast prompts' latency and tokens cold (KV
cache reset) and warm-prefix (only the changed tail evaluated), medians over ``repeats``; the cache-hit
latency through ``ParamAdvisor``; and zero- and few-shot replies on five scenes with simple behaviour checks
(do parameters vary, does a close leader raise ``k_np``, which few-shot example is copied). Minutes per model.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from letspi.llm.backends.llamacpp import LlamaCppBackend
from letspi.llm.cache import ResponseCache
from letspi.llm.client import ParamAdvisor, RetryPolicy
from letspi.llm.compact import render_compact_prompt
from letspi.llm.describe import ScenarioDescription, describe_scenario
from letspi.llm.prompts import MemoryExample, render_fast_prompt, render_physics_prompt
from letspi.llm.schema import NUMERIC_FIELDS, PlannerReply, Variant, reply_json_schema
from letspi.llm.types import DecodingSettings, Message
from letspi.scenario.build import VehicleSpec, straight_road_scenario


def bench_scenarios() -> dict[str, ScenarioDescription]:
    """Five hand-built situations at 30 m/s on a 3-lane road, goal 150 m ahead in the ego lane."""
    cases = {
        "free_road": [],
        "close_leader": [VehicleSpec(x0_m=15.0, speed_mps=22.0)],
        "far_leader": [VehicleSpec(x0_m=80.0, speed_mps=30.0)],
        "beside_left": [VehicleSpec(x0_m=1.0, speed_mps=30.0, lane_offset=1)],
        "fast_follower": [VehicleSpec(x0_m=-15.0, speed_mps=38.0)],
    }
    return {
        name: describe_scenario(straight_road_scenario(neighbours=nbrs, scenario_id=name), (150.0, 0.0))
        for name, nbrs in cases.items()
    }


def _messages(desc: ScenarioDescription, variant: Variant) -> list[Message]:
    return render_physics_prompt(desc) if variant == "physics" else render_fast_prompt(desc)


def _latency(model: str, variant: Variant, descs: dict[str, ScenarioDescription], repeats: int,
             settings: DecodingSettings) -> dict[str, Any]:
    backend = LlamaCppBackend(model)
    llm = backend.loaded().llm  # the instance complete() uses
    a, b = descs["far_leader"], descs["close_leader"]
    cold: list[float] = []
    warm: list[float] = []
    tokens: tuple[int, int] = (0, 0)
    for _ in range(repeats):
        llm.reset()  # forget the KV cache: the whole prompt is evaluated
        r = backend.complete(_messages(b, variant), schema=reply_json_schema(variant), settings=settings, timeout_s=600)
        cold.append(r.latency_s)
        tokens = (r.prompt_tokens, r.completion_tokens)
        backend.complete(_messages(a, variant), schema=reply_json_schema(variant), settings=settings, timeout_s=600)
        r = backend.complete(_messages(b, variant), schema=reply_json_schema(variant), settings=settings, timeout_s=600)
        warm.append(r.latency_s)  # shares the static system prompt with the previous call
    med_cold, med_warm = statistics.median(cold), statistics.median(warm)
    return {"prompt_tokens": tokens[0], "output_tokens": tokens[1], "cold_s": round(med_cold, 2),
            "warm_prefix_s": round(med_warm, 2),
            "warm_prefix_speedup": round(med_cold / med_warm, 2) if med_warm > 0 else None}


def _cache_hit(model: str, desc: ScenarioDescription, settings: DecodingSettings) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        cache = ResponseCache(Path(tmp) / "bench.sqlite")
        adv = ParamAdvisor(f"llamacpp:{model}", cache=cache, settings=settings, retry=RetryPolicy(max_attempts=1))
        msgs = render_fast_prompt(desc)
        t0 = time.perf_counter()
        adv.advise(msgs, variant="fast")
        miss = time.perf_counter() - t0
        t0 = time.perf_counter()
        hit_advice = adv.advise(msgs, variant="fast")
        hit = time.perf_counter() - t0
        cache.close()
    return {"miss_s": round(miss, 3), "hit_s": round(hit, 4), "speedup": round(miss / hit) if hit > 0 else None,
            "hit_flag": hit_advice.cached}


def _behaviour(model: str, descs: dict[str, ScenarioDescription], settings: DecodingSettings) -> dict[str, Any]:
    adv = ParamAdvisor(f"llamacpp:{model}", cache=None, settings=settings)
    out: dict[str, Any] = {}
    for variant in ("fast", "physics"):
        replies: dict[str, dict[str, Any]] = {}
        for name, desc in descs.items():
            adv_out = adv.advise(_messages(desc, variant), variant=variant)
            replies[name] = {
                **{k: round(v, 2) for k, v in adv_out.reply.model_dump().items() if k in NUMERIC_FIELDS},
                "fallback": adv_out.fallback,
                "clamped": sorted(adv_out.clamped),
                "attempts": len(adv_out.attempts),
            }
            if variant == "physics":
                replies[name]["rationale"] = adv_out.reply.rationale[:120]
        distinct = {k: len({r[k] for r in replies.values()}) for k in NUMERIC_FIELDS}
        free, close = replies["free_road"], replies["close_leader"]
        out[variant] = {
            "replies": replies,
            "distinct_values_per_field": distinct,
            "constant_fields": [k for k, n in distinct.items() if n == 1],
            "close_leader_raises_k_np": close["k_np"] > free["k_np"],
            "close_leader_shortens_goal": close["lon_factor"] > free["lon_factor"],
            "any_fallback": any(r["fallback"] for r in replies.values()),
        }
    return out


#: Hand-set "validated" answers used as memories in the few-shot check.
FEWSHOT_ANSWERS: dict[str, PlannerReply] = {
    "close_leader": PlannerReply(
        tau_s=1.5, k_np=45.0, k_nf=5.0, k_nl=1.0, k_boundary=1.0, k_cline=0.5, lon_factor=0.9, lane_factor=0.0
    ),
    "free_road": PlannerReply(
        tau_s=0.8, k_np=20.0, k_nf=4.0, k_nl=0.5, k_boundary=1.0, k_cline=0.5, lon_factor=0.3, lane_factor=0.0
    ),
    "beside_left": PlannerReply(
        tau_s=1.0, k_np=25.0, k_nf=5.0, k_nl=3.0, k_boundary=1.5, k_cline=1.0, lon_factor=0.4, lane_factor=0.0
    ),
}


def _fewshot(model: str, descs: dict[str, ScenarioDescription], settings: DecodingSettings) -> dict[str, Any]:
    adv = ParamAdvisor(f"llamacpp:{model}", cache=None, settings=settings)
    mems = [MemoryExample(descs[name].summary_line(), reply) for name, reply in FEWSHOT_ANSWERS.items()]
    rows: dict[str, Any] = {}
    for name, desc in descs.items():
        a = adv.advise(render_fast_prompt(desc, memories=mems), variant="fast")
        got = {k: round(v, 2) for k, v in a.reply.model_dump().items() if k in NUMERIC_FIELDS}
        copied = [m for m, r in FEWSHOT_ANSWERS.items() if all(abs(getattr(r, k) - got[k]) < 1e-6 for k in got)]
        rows[name] = {
            **got,
            "copied": copied[0] if copied else None,
            "copied_matching": bool(copied) and copied[0] == name,
            "fallback": a.fallback,
            "latency_s": round(a.latency_s, 2),
            "prompt_tokens": a.prompt_tokens,
        }
    seen = [n for n in descs if n in FEWSHOT_ANSWERS]
    return {"replies": rows, "matching_copies": sum(rows[n]["copied_matching"] for n in seen), "of_seen": len(seen),
            "exact_copies_total": sum(r["copied"] is not None for r in rows.values())}


def bench_models(models: Sequence[str] = ("smollm2-135m", "gemma3-270m"), *, repeats: int = 2, behaviour: bool = True,
                 max_tokens: int = 200) -> dict[str, Any]:
    """Run the benchmark (see module docstring); returns a JSON-ready dict keyed by model."""
    settings = DecodingSettings(max_tokens=max_tokens)
    descs = bench_scenarios()
    result: dict[str, Any] = {}
    for model in models:
        entry: dict[str, Any] = {}
        t0 = time.perf_counter()
        for variant in ("physics", "fast"):
            entry[variant] = _latency(model, variant, descs, repeats, settings)
        entry["cache"] = _cache_hit(model, descs["close_leader"], settings)
        if behaviour:
            entry["behaviour"] = _behaviour(model, descs, settings)
            entry["fewshot"] = _fewshot(model, descs, settings)
        entry["bench_wall_s"] = round(time.perf_counter() - t0, 1)
        result[model] = entry
    return result


def standard_messages() -> list[Any]:
    """The compact prompt of the standard scene: 30 m/s, a leader 15 m ahead at 22 m/s, 3 lanes."""
    batch = straight_road_scenario(neighbours=[VehicleSpec(x0_m=15.0, speed_mps=22.0),
                                               VehicleSpec(x0_m=-25.0, speed_mps=31.0, lane_offset=1)],
                                   scenario_id="standard")
    return list(render_compact_prompt(describe_scenario(batch, (150.0, 0.0))))
