"""Shared pieces of the concurrency tests: scenarios, runs against the local test server, comparisons."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from letspi.assembly.build import Builder
from letspi.assembly.resolve import Resolver
from letspi.evaluation.results import load_planner_results
from letspi.execution.ordered import RunnerConfig
from letspi.llm.client import RetryPolicy
from letspi.method.memory import MemoryBank
from letspi.method.phases import CollectStats, collect
from letspi.planners.options import PlannerOptions
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import ScenarioBatch, concat_batches

#: Recorded wall times: the only stored values that may differ between two runs of one configuration.
TIMING_KEYS = frozenset({"propose_s", "simulate_s", "latency_s", "uncached_latency_s", "original_latency_s"})
TIMING_COLUMNS = ("inference_s", "info_llm_latency_s", "info_llm_original_latency_s")


def scenarios(n: int, seed: int = 0) -> ScenarioBatch:
    """``n`` different straight-road scenes; some close leaders make reflection rounds happen."""
    rng = np.random.default_rng(seed)
    return concat_batches([
        straight_road_scenario(
            ego_speed_mps=float(rng.uniform(24.0, 34.0)),
            neighbours=[VehicleSpec(x0_m=float(rng.uniform(12.0, 70.0)), speed_mps=float(rng.uniform(16.0, 32.0))),
                        VehicleSpec(x0_m=float(rng.uniform(-30.0, 30.0)), speed_mps=float(rng.uniform(22.0, 34.0)),
                                    lane_offset=1)],
            scenario_id=f"s{i:03d}")
        for i in range(n)
    ])


def options(spec: str, memory: Path | None = None, **kw: Any) -> PlannerOptions:
    return PlannerOptions(llm=spec, fast_llm=spec, goals="kinematic", llm_cache=False, memory=memory, **kw)


def collect_into(bank_path: Path, spec: str, batch: ScenarioBatch, concurrency: int,
                 retry: RetryPolicy | None = None) -> CollectStats:
    config = Resolver(options(spec)).memory_phase()
    phase, _ = Builder(cache=None).memory_phase(config)
    if retry is not None:
        phase.advisor.retry = retry
    with MemoryBank.open(bank_path) as bank:
        return collect(phase, batch, bank, runner=RunnerConfig(concurrency=concurrency))


def _strip_timing(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _strip_timing(v) for k, v in value.items() if k not in TIMING_KEYS}
    if isinstance(value, list):
        return [_strip_timing(v) for v in value]
    return value


def bank_rows(path: Path) -> list[dict[str, Any]]:
    """Every row of a bank in id order, every column (ids included) except ``created_at``, with the
    recorded wall times taken out of the iteration records."""
    conn = sqlite3.connect(path)
    try:
        cur = conn.execute("SELECT * FROM experiences ORDER BY id")
        names = [d[0] for d in cur.description]
        rows = [dict(zip(names, r, strict=True)) for r in cur.fetchall()]
    finally:
        conn.close()
    for row in rows:
        row.pop("created_at")
        row["iterations"] = _strip_timing(json.loads(row["iterations"]))
    return rows


def stored_results(out: Path, planner: str) -> pd.DataFrame:
    """A planner's stored rows (plans included) without the wall-time columns, in dataset order."""
    frame = load_planner_results(out, planner, with_plans=True)
    frame = frame.drop(columns=[c for c in TIMING_COLUMNS if c in frame])
    for col in ("plan_xy_m", "plan_vxy_mps", "plan_goal_xy_m"):
        frame[col] = [np.asarray(v).tobytes() for v in frame[col]]
    return frame
