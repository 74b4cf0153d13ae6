"""``python -m benchmarks.speed data``: how fast the data pipeline is (numbers, not pass/fail)."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from letspi.highd.io import read_recordings
from letspi.scenario.extract import extract_scenarios
from letspi.scenario.store import load_scenarios, save_scenarios
from letspi.scenario.types import concat_batches
from letspi.trafficgen.generate import generate_highd


def bench_data(minutes: float = 10.0, seed: int = 0, n_load: int = 10_000) -> dict[str, float]:
    """Time SUMO generation of ``minutes`` simulated minutes, extraction of its first recording,
    and loading ``n_load`` scenarios from Parquet. Returns a flat dict of measurements."""
    out: dict[str, float] = {"simulated_minutes": minutes}
    with tempfile.TemporaryDirectory(prefix="letspi-bench-") as tmp:
        tmp_dir = Path(tmp)
        t = time.perf_counter()
        generate_highd(tmp_dir / "highd", minutes=minutes, seed=seed)
        out["generate_s"] = time.perf_counter() - t

        t = time.perf_counter()
        recs = read_recordings(tmp_dir / "highd")
        out["read_s"] = time.perf_counter() - t
        rec = recs[0]
        out["tracks_rows"] = float(len(rec.tracks))
        out["vehicles"] = float(len(rec.tracks_meta))

        t = time.perf_counter()
        batch = extract_scenarios([rec])
        dt = time.perf_counter() - t
        out["extract_s"] = dt
        out["scenarios_one_recording"] = float(len(batch))
        out["extract_scenarios_per_s"] = len(batch) / dt

        reps = int(np.ceil(n_load / len(batch)))
        big = concat_batches([batch] * reps).take(np.arange(n_load))
        path = save_scenarios(big, tmp_dir / "scenarios.arrow")
        out["file_mb_per_10k"] = path.stat().st_size / 1e6 * 10_000 / n_load
        load_times = []
        for _ in range(3):
            t = time.perf_counter()
            load_scenarios(path)
            load_times.append(time.perf_counter() - t)
        out["load_n"] = float(n_load)
        out["load_s_median"] = float(np.median(load_times))
    return out
