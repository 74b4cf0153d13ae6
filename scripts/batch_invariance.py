"""Does the learned goal predictor give the same goals for a scenario whatever batch it is computed in?

Usage: python scripts/batch_invariance.py SCENARIOS.arrow [--n 300]

Prints JSON: for sub-batches of the first N windows (1, 3, 64 and 263 rows at several offsets), the
largest difference of the predicted goals from the same rows computed in the whole batch [m], and
whether the scene features alone already differ; then, for random inputs of the goal predictor's
layer shapes, how many of the same sub-batches a plain ``x @ W`` gets bit-identical to the whole batch,
and how many a fixed 64-row zero-padded block does (notes/closedloop.md, "Planner speed in closed loop").
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from letspi.assembly.planners import build_planners
from letspi.learned.features import scene_features
from letspi.planners.base import PredictingPlanner
from letspi.planners.options import DEFAULT_OPTIONS
from letspi.scenario.store import load_scenarios

SLICES = ((0, 1), (200, 201), (5, 8), (10, 74), (100, 164), (3, 67), (37, 300))
BLOCK_ROWS = 64


def blocked(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``x @ w`` in fixed blocks of ``BLOCK_ROWS`` rows (the last one zero-padded)."""
    pad = (-len(x)) % BLOCK_ROWS
    xp = np.concatenate([x, np.zeros((pad, x.shape[1]))]) if pad else x
    out = np.empty((len(xp), w.shape[1]))
    for s in range(0, len(xp), BLOCK_ROWS):
        np.matmul(np.ascontiguousarray(xp[s:s + BLOCK_ROWS]), w, out=out[s:s + BLOCK_ROWS])
    return out[: len(x)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenarios", type=Path)
    parser.add_argument("--n", type=int, default=300)
    args = parser.parse_args()
    batch = load_scenarios(args.scenarios).take(np.arange(args.n)).history()
    planner = build_planners(["sf"], DEFAULT_OPTIONS)[0].planner
    assert isinstance(planner, PredictingPlanner)
    predictor = planner.goal_predictor
    whole = predictor.predict_goals(batch).top
    features = scene_features(batch)
    slices = [(lo, hi) for lo, hi in SLICES if hi <= args.n]
    goals = {}
    for lo, hi in slices:
        part = batch.take(np.arange(lo, hi))
        sub = scene_features(part)
        goals[f"{lo}:{hi}"] = {
            "goal_diff_m": float(np.abs(predictor.predict_goals(part).top - whole[lo:hi]).max()),
            "features_differ": not (np.array_equal(sub.lane, features.lane[lo:hi], equal_nan=True)
                                    and np.array_equal(sub.anchor_xy, features.anchor_xy[lo:hi], equal_nan=True)),
        }
    rng = np.random.default_rng(0)
    products = {}
    for k, n in ((12, 64), (64, 64), (64, 18), (81, 64), (128, 64)):
        x = rng.normal(size=(300, k))
        w = np.ascontiguousarray(rng.normal(size=(n, k)).T)
        plain, fixed = x @ w, blocked(x, w)
        products[f"{k}x{n}"] = {
            "plain_identical": sum(np.array_equal(plain[lo:hi], x[lo:hi] @ w) for lo, hi in SLICES),
            "blocked_identical": sum(np.array_equal(fixed[lo:hi], blocked(x[lo:hi], w)) for lo, hi in SLICES),
            "sub_batches": len(SLICES),
        }
    print(json.dumps({"n": args.n, "goals": goals, "products": products}, indent=1))


if __name__ == "__main__":
    main()
