"""Start-up time of the command line and the Python API: median of N runs each, against the targets.

Usage: python scripts/startup_time.py [--n 5] [--json]

Runs each probe N times as a fresh process of this interpreter and prints, per probe, the median and
the spread of the wall times [s], the target and the ratio median / target, then the 1-minute load
average before and after. The probes: bare ``python -c pass`` (the floor), ``letspi --help``,
``letspi planners`` and ``import letspi.api``. Run it alone on an idle machine (through the CPU lock).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

#: (name, arguments after the interpreter, target [s] or None)
PROBES: tuple[tuple[str, tuple[str, ...], float | None], ...] = (
    ("python -c pass", ("-c", "pass"), None),
    ("letspi --help", ("-m", "letspi.cli.app", "--help"), 0.5),
    ("letspi planners", ("-m", "letspi.cli.app", "planners"), 1.5),
    ("import letspi.api", ("-c", "import letspi.api"), 1.0),
)


def wall_times_s(args: tuple[str, ...], n: int) -> list[float]:
    """Wall times [s] of ``n`` fresh runs of this interpreter with ``args`` (each must exit 0)."""
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, *args], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        times.append(time.perf_counter() - t0)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--n", type=int, default=5, help="runs per probe (the median is reported)")
    parser.add_argument("--json", action="store_true", help="one JSON object per probe instead of a table")
    args = parser.parse_args()
    load0 = os.getloadavg()[0]
    rows = []
    for name, probe, target in PROBES:
        times = wall_times_s(probe, args.n)
        median = statistics.median(times)
        rows.append({"probe": name, "median_s": round(median, 3), "min_s": round(min(times), 3),
                     "max_s": round(max(times), 3), "target_s": target,
                     "ratio": None if target is None else round(median / target, 2)})
    load1 = os.getloadavg()[0]
    if args.json:
        for row in rows:
            print(json.dumps({**row, "n": args.n, "load_1min": [round(load0, 2), round(load1, 2)]}))
        return
    print(f"{'probe':<20} {'median s':>9} {'min s':>7} {'max s':>7} {'target s':>9} {'ratio':>6}")
    for row in rows:
        target = "" if row["target_s"] is None else f"{row['target_s']:.2f}"
        ratio = "" if row["ratio"] is None else f"{row['ratio']:.2f}"
        print(f"{row['probe']:<20} {row['median_s']:>9.3f} {row['min_s']:>7.3f} {row['max_s']:>7.3f} "
              f"{target:>9} {ratio:>6}")
    print(f"median of {args.n} runs each; load (1 min) {load0:.2f} before, {load1:.2f} after")


if __name__ == "__main__":
    main()
