"""Memory retrieval benchmark (``python -m benchmarks.speed llm``): top-k over the whole bank at 10k and 100k entries.

For each size a temporary bank is filled with synthetic experiences (plausible feature ranges, one
transaction), closed and reopened (cold), then timed:

* ``load_s``: first ``features_matrix()`` (SQLite -> (M, 6) NumPy), ``cached_load_s``: the second call;
* ``topk_batch_s``: ``top_k`` of ``n_queries`` queries in one call; ``topk_single_ms``: mean per query
  when queries come one at a time (the fast phase's situation);
* ``retrieval_single_ms``: one query end to end (cached features + top-k + ``get`` of the k rows).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from letspi.assembly.build import Builder
from letspi.assembly.resolve import Resolver
from letspi.method.matching import top_k
from letspi.method.memory import Experience, MemoryBank
from letspi.method.phases import FastPhase, Retriever, collect
from letspi.physics.params import SocialForceParams
from letspi.planners.options import DEFAULT_OPTIONS
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import concat_batches


def synthetic_features(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 6) features in ``FEATURE_NAMES`` order with highway-like ranges."""
    n_veh = rng.integers(0, 9, n).astype(np.float64)
    speed = rng.uniform(15.0, 40.0, n)
    lane_change = (rng.random(n) < 0.15).astype(np.float64)
    min_dist = rng.uniform(5.0, 100.0, n)
    mean_dist = np.maximum(min_dist, rng.uniform(10.0, 100.0, n))
    nbr_speed = speed + rng.normal(0.0, 3.0, n)
    return np.stack([n_veh, speed, lane_change, min_dist, mean_dist, nbr_speed], axis=1)


def _experiences(features: np.ndarray, start: int) -> list[Experience]:
    params = SocialForceParams()
    metrics = {"min_ttc_s": float("inf"), "min_path_gap_m": 20.0, "safe": 1.0}
    return [
        Experience(
            scenario_id=f"bench_{start + i}", scenario_digest=f"bench_{start + i}", recording_key="bench",
            recording_id=1, ego_id=start + i, frame0=100, config_key="bench", features=tuple(map(float, f)),
            params=params,
            lon_factor=0.4, lane_factor=0.0, metrics_before=metrics, metrics_after=metrics,
            iterations=[{"iteration": 0, "metrics": metrics}], model="bench", prompt=None, reply=None,
            rationale="synthetic", validated=True,
        )
        for i, f in enumerate(features)
    ]


def bench_retrieval(
    n_memories: tuple[int, ...] = (10_000, 100_000),
    n_queries: int = 100,
    k: int = 5,
    seed: int = 0,
    workdir: str | Path | None = None,
) -> dict[str, Any]:
    """Timings [s, ms] per bank size (keys: module doc); ``{"k": k, "n_queries": ..., "sizes": {n: {...}}}``."""
    rng = np.random.default_rng(seed)
    out: dict[str, Any] = {"k": k, "n_queries": n_queries, "sizes": {}}
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        for n in n_memories:
            path = Path(tmp) / f"bench_{n}.sqlite"
            feats = synthetic_features(n, rng)
            queries = synthetic_features(n_queries, rng)
            t0 = time.perf_counter()
            with MemoryBank.open(path, synchronous="NORMAL") as bank:
                for start in range(0, n, 20_000):
                    bank.add_many(_experiences(feats[start:start + 20_000], start))
            insert_s = time.perf_counter() - t0
            with MemoryBank.open(path, readonly=True) as bank:
                t0 = time.perf_counter()
                mem = bank.features_matrix()
                load_s = time.perf_counter() - t0
                t0 = time.perf_counter()
                mem = bank.features_matrix()
                cached_s = time.perf_counter() - t0
                t0 = time.perf_counter()
                top_k(queries, mem.features, k)
                batch_s = time.perf_counter() - t0
                t0 = time.perf_counter()
                for q in queries:
                    top_k(q[None], mem.features, k)
                single_ms = 1000.0 * (time.perf_counter() - t0) / max(n_queries, 1)
                t0 = time.perf_counter()
                n_end = min(n_queries, 20)
                for q in queries[:n_end]:
                    m = bank.features_matrix()
                    idx, _ = top_k(q[None], m.features, k)
                    bank.get(m.ids[idx[0]])
                e2e_ms = 1000.0 * (time.perf_counter() - t0) / max(n_end, 1)
            out["sizes"][n] = {
                "insert_s": insert_s,
                "db_mb": path.stat().st_size / 1e6,
                "load_s": load_s,
                "cached_load_s": cached_s,
                "topk_batch_s": batch_s,
                "topk_single_ms": single_ms,
                "retrieval_single_ms": e2e_ms,
            }
    return out


def bench_phases(model_spec: str = "llamacpp:smollm2-135m", n_scenarios: int = 3) -> dict[str, float]:
    """Per-phase latency with a real model (response cache off): the memory-collection phase (prompt,
    reflection loop, simulation) and the fast phase (retrieval + fast prompt + one call), medians
    over ``n_scenarios`` hand-built scenarios [s]."""
    scenes = [
        straight_road_scenario(ego_speed_mps=30.0 + i, scenario_id=f"b{i}",
                               neighbours=[VehicleSpec(x0_m=35.0 + 10 * i, speed_mps=24.0),
                                           VehicleSpec(x0_m=-20.0, speed_mps=31.0, lane_offset=1)])
        for i in range(n_scenarios)
    ]
    options = DEFAULT_OPTIONS.replace(llm=model_spec, goals="kinematic", llm_cache=False)
    phase, load_s = Builder(cache=None).memory_phase(Resolver(options).memory_phase())
    advisor, goals = phase.advisor, phase.goal_predictor
    out: dict[str, float] = {"model_load_s": load_s}
    with tempfile.TemporaryDirectory() as tmp:
        with MemoryBank.open(Path(tmp) / "m.sqlite") as bank:
            t0 = time.perf_counter()
            collect(phase, concat_batches(scenes), bank)
            out["memory_phase_s_per_scenario"] = (time.perf_counter() - t0) / n_scenarios
            fast = FastPhase(advisor, goals, phase.r_col_m, Retriever(bank, k=3, allow_same_vehicle=True))
            times = []
            for sc in scenes:
                t0 = time.perf_counter()
                fast.propose(sc, goals.predict_goals(sc).top[0])
                times.append(time.perf_counter() - t0)
            out["fast_phase_s_median"] = float(np.median(times))
            out["memories_stored"] = float(bank.count(validated_only=False))
    out["speedup_fast_vs_memory"] = out["memory_phase_s_per_scenario"] / out["fast_phase_s_median"]
    return out
