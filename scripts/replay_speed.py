"""Closed-loop speed of planners in the log replay, per chunk size (scenarios planned per call).

Usage: python scripts/replay_speed.py SCENARIOS.arrow [--n 256] [--planners sf,sf-check] [--chunks 32,256]
                                      [--workers 0] [--replan-s 0.2]

Runs ``closed-loop-log`` (the replay) of the first N windows of a scenario file for every planner and
chunk size, one after the other in this process (``--workers 0``) or on worker processes, and prints one
JSON line per run: wall and CPU ms per window (CPU of this process: meaningful with ``--workers 0``), the
chunk size, the largest difference of the ego trajectory from the planner's first chunk size [m], and
the 1-minute load average before and after. Run it alone on an idle machine (through the CPU lock).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from letspi.scenario.store import load_scenarios
from letspi.simulation import ClosedLoopChunk, ClosedLoopConfig, PlannerSpec, run_closed_loop


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenarios", type=Path)
    parser.add_argument("--n", type=int, default=256)
    parser.add_argument("--planners", default="sf,sf-check")
    parser.add_argument("--chunks", default="32,256")
    parser.add_argument("--workers", type=int, default=0)
    parser.add_argument("--replan-s", type=float, default=0.2)
    args = parser.parse_args()
    batch = load_scenarios(args.scenarios).take(np.arange(args.n))
    for kind in args.planners.split(","):
        first: np.ndarray | None = None
        for size in (int(c) for c in args.chunks.split(",")):
            config = ClosedLoopConfig(mode="closed-loop-log", replan_s=args.replan_s,  # type: ignore[arg-type]
                                      chunk_size=size, workers=args.workers, simulator="replay")
            load0 = os.getloadavg()[0]
            w0, c0 = time.perf_counter(), time.process_time()
            chunk = ClosedLoopChunk.concat(list(run_closed_loop(PlannerSpec.of(kind), batch, config)))
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
            ego = chunk.take(np.argsort(chunk.indices)).ego_xy_m
            first = ego if first is None else first
            print(json.dumps({
                "planner": kind, "chunk_size": size, "workers": args.workers, "n": args.n,
                "wall_ms_per_window": round(1e3 * wall / args.n, 2), "cpu_ms_per_window": round(1e3 * cpu / args.n, 2),
                "max_ego_diff_m": float(np.nanmax(np.abs(ego - first))),
                "load_1min": [round(load0, 2), round(os.getloadavg()[0], 2)],
            }), flush=True)


if __name__ == "__main__":
    main()
