"""Degenerate scenes through every planner and every metric: crashes and NaN counts (must be 0).

``bench_robustness`` builds ``n`` scenes of ``benchmarks/degenerate.py`` (random, no neighbours,
8 neighbours overlapping the ego at t = 0, zero speed, a 1-lane road, NaN gaps in neighbour
tracks), plans them with every planner kind of the table that needs no LLM (``PLAIN_PLANNERS``; a
kind whose setting has no default, such as ``mlp`` without ``--mlp-weights``, is reported as
skipped) and, on the first ``n_llm`` scenes, with the LLM planners on the scripted backend
(``LLM_PLANNERS``; letspi-fast and letspi-fs with a memory collected on those scenes), and computes
every metric.

Counted per planner: crashes (a ``plan`` or ``compute_metrics`` call that raised; a failing chunk
is retried scene by scene so every crashing scene is counted once), NaN per metric column (a float
metric must be finite or +inf, see ``letspi.metrics.registry``), plans that are not finite, and
``nan_aggregates`` (None or NaN where ``aggregate_metrics`` must give a number).
"""

from __future__ import annotations

import math
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from benchmarks.degenerate import DEGENERATE_KINDS, degenerate_scenarios, scene_kind
from letspi.assembly.build import Builder
from letspi.assembly.planner_table import BUILT_IN
from letspi.assembly.planners import BuiltPlanner, build_planners
from letspi.assembly.resolve import Resolver
from letspi.method.memory import MemoryBank
from letspi.method.phases import collect
from letspi.metrics.aggregate import aggregate_metrics
from letspi.metrics.compute import compute_metrics
from letspi.planners.llm import MEMORY
from letspi.planners.options import DEFAULT_OPTIONS, PlannerOptions
from letspi.scenario.types import ScenarioBatch

PLAIN_PLANNERS = tuple(kind.name for kind in BUILT_IN.kinds if not kind.uses_llm)
LLM_PLANNERS = tuple(kind.name for kind in BUILT_IN.kinds if kind.uses_llm)
SCRIPTED = "scripted:default"
CHUNK = 500


def _plan_and_score(built: BuiltPlanner, sub: ScenarioBatch) -> pd.DataFrame:
    plan = built.planner.plan(sub if built.reads_future else sub.history())
    frame = compute_metrics(sub, plan.xy_m, plan.vxy_mps, plan.goals_xy_m).to_frame()
    frame["plan_finite"] = np.isfinite(plan.xy_m).all(axis=(1, 2)) & np.isfinite(plan.vxy_mps).all(axis=(1, 2))
    return frame


def _run_planner(built: BuiltPlanner, batch: ScenarioBatch, chunk: int) -> tuple[pd.DataFrame, list[str]]:
    """All scenes' metric rows (crashed scenes left out) and one message per crashed scene."""
    frames: list[pd.DataFrame] = []
    crashes: list[str] = []
    step = max(1, min(chunk, int(built.planner.batch_size)))
    for start in range(0, len(batch), step):
        idx = np.arange(start, min(len(batch), start + step))
        try:
            frames.append(_plan_and_score(built, batch.take(idx)))
            continue
        except Exception:  # counted below, scene by scene
            pass
        for i in idx:
            try:
                frames.append(_plan_and_score(built, batch.take([int(i)])))
            except Exception as exc:  # what this benchmark counts
                crashes.append(f"{batch.scenario_id[i]}: {type(exc).__name__}: {exc}")
    return (pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()), crashes


def _nan_counts(frame: pd.DataFrame) -> dict[str, int]:
    out = {}
    for col in frame.columns:
        if frame[col].dtype.kind == "f":
            out[col] = int(np.isnan(frame[col].to_numpy()).sum())
    return out


def _nan_aggregates(frame: pd.DataFrame) -> list[str]:
    if not len(frame):
        return []
    agg = aggregate_metrics(frame.drop(columns=["plan_finite"]), inference_time_s=np.zeros(len(frame)))
    return [k for k, v in agg.items() if isinstance(v, float) and (math.isnan(v))]


def _llm_planners(sub: ScenarioBatch, bank_dir: Path, options: PlannerOptions) -> list[BuiltPlanner]:
    options = options.replace(llm=SCRIPTED, fast_llm=SCRIPTED, goals="kinematic", llm_cache=False,
                              memory=bank_dir / "memory.sqlite", allow_same_vehicle=True)
    phase, _ = Builder(cache=None).memory_phase(Resolver(options).memory_phase())
    with MemoryBank.open(options.get(MEMORY)) as bank:  # type: ignore[arg-type]
        collect(phase, sub, bank)
    return build_planners(list(LLM_PLANNERS), options)


def _plain_planners(options: PlannerOptions, say: Callable[[str], None]) -> tuple[list[BuiltPlanner], dict[str, str]]:
    """The planners without an LLM, and the kinds skipped because a setting they need was not given."""
    built: list[BuiltPlanner] = []
    skipped: dict[str, str] = {}
    builder = Builder(cache=None)
    for kind in PLAIN_PLANNERS:
        try:
            built += build_planners([kind], options, builder=builder)
        except ValueError as exc:  # e.g. mlp without --mlp-weights: nothing to plan with
            skipped[kind] = str(exc)
            say(f"{kind}: skipped ({exc})")
    return built, skipped


def bench_robustness(n: int = 10_000, *, seed: int = 0, n_llm: int = 300, chunk: int = CHUNK,
                     options: PlannerOptions = DEFAULT_OPTIONS,
                     log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Counts of crashes and NaN per planner and metric over ``n`` degenerate scenes (module doc);
    ``options``: the planners' settings (the LLM planners run on the scripted backend regardless)."""
    say = log or (lambda _msg: None)
    t0 = time.perf_counter()
    batch = degenerate_scenarios(n, seed=seed)
    kinds = Counter(scene_kind(str(s)) for s in batch.scenario_id)
    say(f"built {n} scenes in {time.perf_counter() - t0:.1f} s")
    planners, skipped = _plain_planners(options.replace(llm_cache=False), say)
    runs: list[tuple[BuiltPlanner, ScenarioBatch]] = [(b, batch) for b in planners]
    n_llm = min(n_llm, n)
    with tempfile.TemporaryDirectory(prefix="letspi-robustness-") as tmp:
        if n_llm:
            sub = batch.take(np.arange(n_llm))
            runs += [(b, sub) for b in _llm_planners(sub, Path(tmp), options)]
        per_planner: dict[str, dict[str, Any]] = {}
        for built, scenes in runs:
            t1 = time.perf_counter()
            frame, crashes = _run_planner(built, scenes, chunk)
            nan = _nan_counts(frame)
            per_planner[built.name] = {
                "scenarios": len(scenes),
                "crashes": len(crashes),
                "crash_examples": crashes[:3],
                "nan_values": int(sum(nan.values())),
                "nan_by_metric": {k: v for k, v in nan.items() if v},
                "metrics_checked": len(nan),
                "plans_not_finite": int((~frame["plan_finite"]).sum()) if len(frame) else 0,
                "nan_aggregates": _nan_aggregates(frame),
                "seconds": round(time.perf_counter() - t1, 1),
            }
            say(f"{built.name}: {len(scenes)} scenes, {len(crashes)} crashes, {sum(nan.values())} NaN "
                f"({per_planner[built.name]['seconds']} s)")
    return {
        "scenarios": n,
        "seed": seed,
        "scenarios_by_kind": {k: kinds.get(k, 0) for k in DEGENERATE_KINDS},
        "llm_subset": n_llm,
        "crashes": sum(p["crashes"] for p in per_planner.values()),
        "nan_values": sum(p["nan_values"] for p in per_planner.values()),
        "nan_aggregates": sum(len(p["nan_aggregates"]) for p in per_planner.values()),
        "plans_not_finite": sum(p["plans_not_finite"] for p in per_planner.values()),
        "planners": per_planner,
        "skipped": skipped,
        "seconds": round(time.perf_counter() - t0, 1),
    }
