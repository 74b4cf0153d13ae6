"""Paired comparisons and leaderboards from stored per-scenario results, without planning anything.

Usage:
    python scripts/pair_results.py ROOT REFERENCE PLANNER [PLANNER ...] [--mode MODE] [--suite NAME ...]
    python scripts/pair_results.py ROOT --leaderboards OUT PLANNER [PLANNER ...] [--mode MODE]

ROOT holds one `letspi benchmark run --out ROOT/SUITE` directory per suite (ROOT/SUITE/MODE/per_scenario/LABEL);
MODE defaults to open-loop. Windows are paired by scenario digest over every suite present (or those --suite
names), pooled.

The first form prints, per planner against REFERENCE: CR at fault and SR (%), the windows only one of the two is at
fault in and the exact McNemar p, and the same for successes. The second writes OUT/SUITE/leaderboard.json for the
labels given (``sf`` first: it is the reference of the cells), so that `letspi benchmark summary OUT/SUITE ...
--mode MODE` prints the README's cells (Wilson intervals at the effective n of windows grouped by ego vehicle).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.stats import binomtest

from letspi.analysis.decisions import paired_rows
from letspi.benchmark.data import prepare_data
from letspi.benchmark.leaderboard import leaderboard, mode_board, to_json
from letspi.benchmark.suites import SUITES, get_suite
from letspi.scenario.identity import dataset_digest, scenario_digests
from letspi.scenario.split import vehicle_keys
from letspi.scenario.store import load_scenarios


def _discordant(mine: np.ndarray, ref: np.ndarray) -> str:
    only_mine, only_ref = int((mine & ~ref).sum()), int((ref & ~mine).sum())
    p = binomtest(only_mine, only_mine + only_ref).pvalue if only_mine + only_ref else 1.0
    return f"{only_mine} / {only_ref}, p {p:.2g}"


def pair(dirs: list[Path], reference: str, planners: list[str]) -> None:
    for name in planners:
        p = paired_rows(dirs, name, reference)
        fault = [np.asarray(x["collision_at_fault"], dtype=bool) for x in (p.planner, p.reference)]
        success = [np.asarray(x["success"], dtype=bool) for x in (p.planner, p.reference)]
        print(f"{name} vs {reference} (n {len(p.planner)}): CR at fault {100 * fault[0].mean():.2f} vs "
              f"{100 * fault[1].mean():.2f} % (only it / only ref at fault {_discordant(*fault)}); SR "
              f"{100 * success[0].mean():.2f} vs {100 * success[1].mean():.2f} % (only it / only ref succeeds "
              f"{_discordant(*success)})")


def leaderboards(root: Path, mode: str, out: Path, planners: list[str]) -> None:
    for name in SUITES:
        eval_dir = root / name / mode
        if not eval_dir.is_dir():
            continue
        suite = get_suite(name)
        full = load_scenarios(prepare_data(suite, log=lambda _m: None).scenarios_file)
        digests = scenario_digests(full)
        groups_of = dict(zip(digests.tolist(), vehicle_keys(full).tolist(), strict=True))
        present = [p for p in planners if (eval_dir / "per_scenario" / p).is_dir()]
        reference = "sf" if "sf" in present else None
        board = leaderboard(suite, {mode: mode_board(eval_dir, present, groups_of, reference)},
                            dataset_digest(digests))
        (out / name).mkdir(parents=True, exist_ok=True)
        (out / name / "leaderboard.json").write_text(to_json(board))
        print(f"{out / name}/leaderboard.json: {', '.join(present)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", type=Path)
    parser.add_argument("labels", nargs="+", help="REFERENCE PLANNER..., or with --leaderboards PLANNER...")
    parser.add_argument("--mode", default="open-loop")
    parser.add_argument("--leaderboards", type=Path, default=None, metavar="OUT")
    parser.add_argument("--suite", action="append", default=None, help="Only this suite (repeatable)")
    args = parser.parse_args()
    if args.leaderboards is not None:
        leaderboards(args.root, args.mode, args.leaderboards, args.labels)
        return
    suites = [s for s in SUITES if args.suite is None or s in args.suite]
    dirs = [args.root / s / args.mode for s in suites if (args.root / s / args.mode).is_dir()]
    if not dirs or len(args.labels) < 2:
        parser.error(f"needs ROOT/SUITE/{args.mode} directories and REFERENCE PLANNER...")
    reference, *planners = args.labels
    dirs = [d for d in dirs if (d / "per_scenario" / reference).is_dir()]
    pair(dirs, reference, planners)


if __name__ == "__main__":
    main()
