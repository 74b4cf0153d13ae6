"""Benchmark: the physics kernels issue 27's speed work made faster, new beside old in one process.

``bench_kernels`` times each kernel and the algorithm it replaced (``benchmarks.replaced``) on the
same synthetic highway scenes (``benchmarks.physics.synthetic_batch``, 8 neighbours each), checks
that both give identical arrays, and reports the ratio old / new:

* ``predict_idm``: the IDM neighbour prediction of the closed-loop planners (``idm``, ``frenet``,
  ``sf``, ``sf-opt``, ``gnp`` at every replan);
* ``sf_opt_check``: the safety check of ``sf-opt``'s candidate plans (C = 27 per scenario) against the
  predicted neighbours; the old one gets the batch and the prediction already repeated per candidate
  (in ``sf-opt`` that copy was shared with the rollout, so it is not charged to the check);
* ``sf_opt_search``: ``sf-opt``'s search of every candidate (rollouts, check, choice) from the same
  proposals and context, against the search on the batch repeated per candidate;
* ``sf_opt_staged``: ``sf-opt``'s staged search (cheapest candidates first, stop at the first safe one)
  against the search of every candidate. Identical plans and choices; the staged search reports
  ``n_candidates_tried`` where the other counted ``n_safe_candidates``, so info keys only one side has
  are not compared.

Timings are the best of ``repeats`` after one warm-up call: CPU seconds of this process (NumPy's
element-wise kernels are single-threaded, so CPU time is the load-independent figure) and wall
seconds. The load average at the start and the end is part of the result.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import fields
from typing import Any

import numpy as np

from benchmarks.physics import synthetic_batch
from benchmarks.replaced import (
    check_inputs_mirrored,
    predict_idm_concatenating,
    repeated,
    sf_opt_all_candidates,
    sf_opt_on_repeated_batch,
)
from letspi.physics.neighbours import predict_idm
from letspi.physics.social_force import SocialForceScene, rollout_social_force_scene
from letspi.planners.base import PlanBatch
from letspi.planners.sf_opt import SocialForceSearchPlanner, candidates
from letspi.planners.sf_params import load_sf_params
from letspi.safety.plan_check import check_plans, predicted_inputs

KERNELS = ("predict_idm", "sf_opt_check", "sf_opt_search", "sf_opt_staged")


def best_of(fn: Callable[[], Any], repeats: int) -> tuple[float, float, Any]:
    """(CPU ms, wall ms, result) of the fastest of ``repeats`` calls of ``fn`` after a warm-up call."""
    fn()
    cpu, wall, out = [], [], None
    for _ in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        out = fn()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    return 1e3 * min(cpu), 1e3 * min(wall), out


def arrays_of(result: Any, info_keys: set[str] | None = None) -> list[np.ndarray]:
    """Every array of a kernel's result, in a fixed order (a plan's info by key: ``info_keys``, default all)."""
    if isinstance(result, PlanBatch):
        keys = sorted(result.info if info_keys is None else info_keys)
        return [result.xy_m, result.vxy_mps, result.goals_xy_m, *(result.info[k] for k in keys)]
    if isinstance(result, tuple):  # NeighbourPrediction
        return [np.asarray(a) for a in result]
    return [np.asarray(getattr(result, f.name)) for f in fields(result)]


def identical(a: Any, b: Any) -> bool:
    """Whether two kernel results hold the same arrays, bit for bit (NaN equal to NaN); two plans are compared
    on the info keys both have."""
    shared = set(a.info) & set(b.info) if isinstance(a, PlanBatch) and isinstance(b, PlanBatch) else None
    xs, ys = arrays_of(a, shared), arrays_of(b, shared)
    return len(xs) == len(ys) and all(
        x.shape == y.shape and np.array_equal(x, y, equal_nan=x.dtype.kind == "f") for x, y in zip(xs, ys, strict=True)
    )


def kernel_pairs(n_scenarios: int, seed: int) -> tuple[dict[str, tuple[Callable[[], Any], Callable[[], Any]]], int]:
    """The (new, old) calls of each kernel on ``n_scenarios`` synthetic scenes, and the number of
    ``sf-opt`` candidates per scenario."""
    batch = synthetic_batch(n_scenarios, seed).history()
    planner = SocialForceSearchPlanner(params=load_sf_params()[0])
    context = planner.context(batch)
    proposals = planner.propose(batch, context)
    pred = context.neighbours
    rows, params, goals = candidates(planner.space, batch, context.goals_xy_m, proposals)
    roll = rollout_social_force_scene(SocialForceScene.from_batch(batch, pred).take(rows), params, goals)
    big, big_pred = batch.take(rows), repeated(pred, rows)
    pairs = {
        "predict_idm": (lambda: predict_idm(batch), lambda: predict_idm_concatenating(batch)),
        "sf_opt_check": (
            lambda: check_plans(batch, roll.xy_m, roll.vxy_mps, pred, rows=rows),
            lambda: check_inputs_mirrored(big, predicted_inputs(big, roll.xy_m, roll.vxy_mps, big_pred)),
        ),
        "sf_opt_search": (
            lambda: sf_opt_all_candidates(planner, batch, context, proposals),
            lambda: sf_opt_on_repeated_batch(planner, batch, context, proposals),
        ),
        "sf_opt_staged": (
            lambda: planner.simulate(batch, context, proposals),
            lambda: sf_opt_all_candidates(planner, batch, context, proposals),
        ),
    }
    return pairs, len(rows) // n_scenarios


def bench_kernels(n_scenarios: int = 256, seed: int = 0, repeats: int = 3) -> dict[str, float]:
    """CPU and wall ms of each kernel of ``KERNELS`` (new and old) on one batch of ``n_scenarios``,
    the CPU ratio old / new, whether both gave identical results (1 / 0), and the 1-minute load
    average before and after."""
    load_start = os.getloadavg()[0]
    pairs, n_candidates = kernel_pairs(n_scenarios, seed)
    result: dict[str, float] = {"n_scenarios": float(n_scenarios), "sf_opt_candidates": float(n_candidates)}
    for name, (new, old) in pairs.items():
        new_cpu, new_wall, new_out = best_of(new, repeats)
        old_cpu, old_wall, old_out = best_of(old, repeats)
        result |= {
            f"{name}_new_cpu_ms": new_cpu, f"{name}_old_cpu_ms": old_cpu, f"{name}_speedup": old_cpu / new_cpu,
            f"{name}_new_wall_ms": new_wall, f"{name}_old_wall_ms": old_wall,
            f"{name}_identical": float(identical(new_out, old_out)),
        }
    return result | {"load_1min_start": load_start, "load_1min_end": os.getloadavg()[0]}
