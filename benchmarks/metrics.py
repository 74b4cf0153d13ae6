"""Benchmark of ``compute_metrics`` against plain per-scenario Python loops of the same maths.

``bench_metrics`` builds a synthetic highway batch (random lanes, speeds, cars and trucks, ego
plans with and without a lane change), times the vectorised metrics on all scenarios and the
scalar ``_reference`` implementations on a subset (extrapolated), and reports scenarios/s and
the speed-up. The references are also what the tests compare the vectorised code against.

Run: ``python -m benchmarks.metrics [n_scenarios]``.
"""

from __future__ import annotations

import math
import sys
import time
from typing import Any

import numpy as np

from letspi.constants import DT_S, MAX_NEIGHBOURS, N_FUTURE, N_TOTAL, T0_INDEX
from letspi.metrics.compute import compute_metrics
from letspi.metrics.config import MetricsConfig
from letspi.metrics.distance import distances
from letspi.metrics.inputs import MetricInputs
from letspi.metrics.pet import pet_grid
from letspi.metrics.ttc import rear_ttc_1d, ttc_1d
from letspi.metrics.ttc2d import ttc_2d
from letspi.scenario.types import VEHICLE_CLASS_CAR, VEHICLE_CLASS_TRUCK, ScenarioBatch

LANE_W = 3.75


def synthetic_batch(n: int, seed: int = 0) -> tuple[ScenarioBatch, np.ndarray, np.ndarray, np.ndarray]:
    """A random 3-lane highway batch and ego plans: (batch, plan_xy (B,F,2), plan_vxy, goals (B,2)).

    Every vehicle moves at constant acceleration (speeds stay positive); about a third of the
    plans change lane with a 4 s smoothstep, the rest follow the human with a speed offset.
    """
    rng = np.random.default_rng(seed)
    m = MAX_NEIGHBOURS
    t = (np.arange(N_TOTAL) - T0_INDEX) * DT_S  # (T,)
    ego_lane, ego_x, ego_xy, ego_v, ego_a = _random_ego(rng, n, t)
    marking_y = (np.arange(4)[None, :] - ego_lane[:, None] - 0.5) * LANE_W

    valid_slot, lane, truck, nlen, nwid, nbr_xy, nbr_v, valid = _random_neighbours(rng, ego_lane, t)

    lane_ids = np.broadcast_to(np.array([8, 7, 6], dtype=np.int8), (n, 3)).copy()
    batch = ScenarioBatch(
        scenario_id=np.array([f"syn_{i}" for i in range(n)], dtype=object),
        recording_id=np.zeros(n, np.int32),
        recording_key=np.full(n, "synthetic", dtype=object),
        location_id=np.zeros(n, np.int32),
        ego_id=np.ones(n, np.int32),
        frame0=np.full(n, T0_INDEX + 1, np.int32),
        driving_direction=np.full(n, 2, np.int8),
        speed_limit_mps=np.full(n, np.nan, np.float32),
        ego_class=np.full(n, VEHICLE_CLASS_CAR, np.int8),
        ego_length_m=np.full(n, 4.5, np.float32),
        ego_width_m=np.full(n, 1.8, np.float32),
        ego_xy_m=ego_xy.astype(np.float32),
        ego_vxy_mps=ego_v.astype(np.float32),
        ego_axy_mps2=ego_a.astype(np.float32),
        ego_lane_id=lane_ids[np.arange(n), ego_lane][:, None].repeat(N_TOTAL, 1),
        nbr_id=np.where(valid_slot, np.arange(m)[None] + 2, 0).astype(np.int32),
        nbr_class=np.where(valid_slot, np.where(truck, VEHICLE_CLASS_TRUCK, VEHICLE_CLASS_CAR), -1).astype(np.int8),
        nbr_length_m=np.where(valid_slot, nlen, 0).astype(np.float32),
        nbr_width_m=np.where(valid_slot, nwid, 0).astype(np.float32),
        nbr_xy_m=nbr_xy.astype(np.float32),
        nbr_vxy_mps=nbr_v.astype(np.float32),
        nbr_valid=valid,
        nbr_lane_id=np.where(valid, lane_ids[np.arange(n)[:, None], lane][..., None], 0).astype(np.int8),
        marking_y_m=marking_y.astype(np.float32),
        marking_is_edge=np.broadcast_to(np.array([True, False, False, True]), (n, 4)).copy(),
        lane_ids=lane_ids,
        ctx_id=np.zeros((n, 0), np.int32),
        ctx_class=np.zeros((n, 0), np.int8),
        ctx_length_m=np.zeros((n, 0), np.float32),
        ctx_width_m=np.zeros((n, 0), np.float32),
        ctx_xy_m=np.zeros((n, 0, N_FUTURE, 2), np.float32),
        ctx_vxy_mps=np.zeros((n, 0, N_FUTURE, 2), np.float32),
        ctx_valid=np.zeros((n, 0, N_FUTURE), bool),
    )

    plan_xy, plan_vxy = _random_plans(rng, ego_x[:, batch.future_slice], ego_v[:, batch.future_slice, 0], ego_lane,
                                      t[batch.future_slice])
    # dv is a velocity jump at t = 0, so many plans fail the feasibility test: irrelevant for timing
    goals = plan_xy[:, -1].copy()
    return batch, plan_xy, plan_vxy, goals


def _random_ego(rng: np.random.Generator, n: int, t: np.ndarray) -> tuple[np.ndarray, ...]:
    """Constant-acceleration egos along y = 0: (lane index (B,), x (B, T), xy, vxy, axy (B, T, 2))."""
    ego_lane = rng.integers(0, 3, n)
    v0 = rng.uniform(20.0, 35.0, n)
    a0 = rng.uniform(-0.5, 0.5, n)
    ego_x = v0[:, None] * t + 0.5 * a0[:, None] * t**2
    ego_xy = np.stack([ego_x, np.zeros_like(ego_x)], -1)
    ego_v = np.stack([v0[:, None] + a0[:, None] * t, np.zeros_like(ego_x)], -1)
    ego_a = np.stack([np.broadcast_to(a0[:, None], ego_x.shape), np.zeros_like(ego_x)], -1)
    return ego_lane, ego_x, ego_xy, ego_v, ego_a


def _random_neighbours(rng: np.random.Generator, ego_lane: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, ...]:
    """Up to ``MAX_NEIGHBOURS`` constant-acceleration neighbours per scenario: (valid slot (B, N), lane
    index, truck flag, length, width (B, N), xy (B, N, T, 2), vxy, valid (B, N, T))."""
    n, m = len(ego_lane), MAX_NEIGHBOURS
    n_valid = rng.integers(2, m + 1, n)
    valid_slot = np.arange(m)[None, :] < n_valid[:, None]
    lane = rng.integers(0, 3, (n, m))
    ny = (lane - ego_lane[:, None]) * LANE_W + rng.uniform(-0.3, 0.3, (n, m))
    nx0 = rng.uniform(-80.0, 80.0, (n, m))
    nv0 = rng.uniform(18.0, 36.0, (n, m))
    na = rng.uniform(-0.8, 0.8, (n, m))
    truck = rng.random((n, m)) < 0.2
    nlen = np.where(truck, rng.uniform(10.0, 18.0, (n, m)), rng.uniform(4.0, 5.2, (n, m)))
    nwid = np.where(truck, 2.5, rng.uniform(1.7, 2.1, (n, m)))
    nx = nx0[..., None] + nv0[..., None] * t + 0.5 * na[..., None] * t**2
    nbr_xy = np.stack([nx, np.broadcast_to(ny[..., None], nx.shape)], -1)
    nbr_v = np.stack([nv0[..., None] + na[..., None] * t, np.zeros_like(nx)], -1)
    valid = np.broadcast_to(valid_slot[..., None], nx.shape).copy()
    return (valid_slot, lane, truck, nlen, nwid, np.where(valid[..., None], nbr_xy, np.nan),
            np.where(valid[..., None], nbr_v, np.nan), valid)


def _random_plans(rng: np.random.Generator, future_x: np.ndarray, future_vx: np.ndarray, ego_lane: np.ndarray,
                  tf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Plans (B, F, 2) xy and vxy: the human future with a speed offset, a third of them with a 4 s
    smoothstep lane change."""
    n = len(ego_lane)
    dv = rng.uniform(-3.0, 3.0, n)
    px = future_x + dv[:, None] * tf
    pvx = future_vx + dv[:, None]
    side = np.where(ego_lane == 0, 1, np.where(ego_lane == 2, -1, rng.choice([-1, 1], n)))
    change = rng.random(n) < 1 / 3
    s = np.clip(tf / 4.0, 0.0, 1.0)
    shape = 3 * s**2 - 2 * s**3
    dshape = np.where(tf < 4.0, (6 * s - 6 * s**2) / 4.0, 0.0)
    py = np.where(change, side * LANE_W, 0.0)[:, None] * shape
    pvy = np.where(change, side * LANE_W, 0.0)[:, None] * dshape
    return np.stack([px, py], -1), np.stack([pvx, pvy], -1)


# Scalar references (plain Python, one scenario at a time) --------------------------------------


def _reference_core(inp: MetricInputs, b: int) -> dict[str, float]:
    """min front and rear 1-D TTC, min 2-D TTC, min centre distance and min box gap of scenario b, by loops."""
    ex, ey = inp.ego_xy_m[b, :, 0], inp.ego_xy_m[b, :, 1]
    evx, evy = inp.ego_vxy_mps[b, :, 0], inp.ego_vxy_mps[b, :, 1]
    n_nbr, n_f = inp.nbr_valid.shape[1:]
    out = {"min_ttc_s": math.inf, "min_rear_ttc_s": math.inf, "min_ttc2d_s": math.inf,
           "min_centre_dist_m": math.inf, "min_box_gap_m": math.inf}
    for f in range(n_f):
        best_dx, lead = math.inf, -1
        best_back, follower = math.inf, -1
        for k in range(n_nbr):
            if not inp.nbr_valid[b, k, f]:
                continue
            dx = float(inp.nbr_xy_m[b, k, f, 0] - ex[f])
            dy = float(inp.nbr_xy_m[b, k, f, 1] - ey[f])
            hx = 0.5 * float(inp.ego_length_m[b] + inp.nbr_length_m[b, k])
            hy = 0.5 * float(inp.ego_width_m[b] + inp.nbr_width_m[b, k])
            out["min_centre_dist_m"] = min(out["min_centre_dist_m"], math.hypot(dx, dy))
            gap = math.hypot(max(abs(dx) - hx, 0.0), max(abs(dy) - hy, 0.0))
            out["min_box_gap_m"] = min(out["min_box_gap_m"], gap)
            if abs(dy) < hy and 0 < dx < best_dx:
                best_dx, lead = dx, k
            if abs(dy) < hy and 0 < -dx < best_back:
                best_back, follower = -dx, k
            rvx = float(inp.nbr_vxy_mps[b, k, f, 0] - evx[f])
            rvy = float(inp.nbr_vxy_mps[b, k, f, 1] - evy[f])
            out["min_ttc2d_s"] = min(out["min_ttc2d_s"], _reference_ttc2d(dx, dy, rvx, rvy, hx, hy))
        if lead >= 0:
            s = best_dx - 0.5 * float(inp.ego_length_m[b] + inp.nbr_length_m[b, lead])
            dv = float(evx[f] - inp.nbr_vxy_mps[b, lead, f, 0])
            ttc = 0.0 if s <= 0 else (s / dv if dv > 0 else math.inf)
            out["min_ttc_s"] = min(out["min_ttc_s"], ttc)
        if follower >= 0:
            s = best_back - 0.5 * float(inp.ego_length_m[b] + inp.nbr_length_m[b, follower])
            dv = float(inp.nbr_vxy_mps[b, follower, f, 0] - evx[f])
            ttc = 0.0 if s <= 0 else (s / dv if dv > 0 else math.inf)
            out["min_rear_ttc_s"] = min(out["min_rear_ttc_s"], ttc)
    return out


def _reference_ttc2d(px: float, py: float, vx: float, vy: float, hx: float, hy: float) -> float:
    """Scalar 2-D box TTC (same definition as ``letspi.metrics.ttc2d``)."""
    entry, exit_ = -math.inf, math.inf
    for p, v, h in ((px, vx, hx), (py, vy, hy)):
        if v == 0:
            if abs(p) >= h:
                return math.inf
            continue
        t1, t2 = (-h - p) / v, (h - p) / v
        entry, exit_ = max(entry, min(t1, t2)), min(exit_, max(t1, t2))
    if entry < exit_ and exit_ > 0:
        return max(entry, 0.0)
    return math.inf


def _reference_pet(inp: MetricInputs, b: int, cell_m: float = 0.5, dt_s: float = DT_S) -> float:
    """Literal grid PET of scenario b: per-cell first/last occupancy in dicts, then the minimum."""

    def occupancy(xs: np.ndarray, ys: np.ndarray, length: float, width: float, ok: np.ndarray) -> dict:
        cells: dict[tuple[int, int], list[int]] = {}
        for f in range(len(xs)):
            if not ok[f]:
                continue
            # a box occupies the cells whose centre ((i + 1/2) c, (j + 1/2) c) it covers strictly
            lo_x, hi_x = xs[f] - length / 2, xs[f] + length / 2
            lo_y, hi_y = ys[f] - width / 2, ys[f] + width / 2
            for i in range(math.floor(lo_x / cell_m) - 1, math.ceil(hi_x / cell_m) + 1):
                if not lo_x < (i + 0.5) * cell_m < hi_x:
                    continue
                for j in range(math.floor(lo_y / cell_m) - 1, math.ceil(hi_y / cell_m) + 1):
                    if lo_y < (j + 0.5) * cell_m < hi_y:
                        first_last = cells.setdefault((i, j), [f, f])
                        first_last[1] = f
        return cells

    n_f = inp.ego_xy_m.shape[1]
    ego = occupancy(
        inp.ego_xy_m[b, :, 0],
        inp.ego_xy_m[b, :, 1],
        float(inp.ego_length_m[b]),
        float(inp.ego_width_m[b]),
        np.ones(n_f, dtype=bool),
    )
    best = math.inf
    for k in range(inp.nbr_valid.shape[1]):
        if not inp.nbr_valid[b, k].any():
            continue
        nbr = occupancy(
            inp.nbr_xy_m[b, k, :, 0],
            inp.nbr_xy_m[b, k, :, 1],
            float(inp.nbr_length_m[b, k]),
            float(inp.nbr_width_m[b, k]),
            inp.nbr_valid[b, k],
        )
        for cell, (a1, b1) in ego.items():
            if cell in nbr:
                a2, b2 = nbr[cell]
                best = min(best, max(a2 - b1, a1 - b2, 0) * dt_s)
    return best


def _time(fn: Any, repeat: int = 1) -> float:
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def bench_metrics(n_scenarios: int = 10_000, seed: int = 0, n_reference: int = 100) -> dict[str, float]:
    """Time vectorised vs loop metrics; returns and prints scenarios/s and speed-ups.

    Keys: n_scenarios, full_sps (all of ``compute_metrics``), core_sps (vectorised front and rear
    1-D TTC, 2-D TTC, distances), core_loop_sps (``_reference_core`` on ``n_reference`` scenarios), core_speedup,
    pet_sps, pet_loop_sps, pet_speedup.
    """
    batch, plan_xy, plan_vxy, goals = synthetic_batch(n_scenarios, seed)
    cfg = MetricsConfig()
    t_full = _time(lambda: compute_metrics(batch, plan_xy, plan_vxy, goals, cfg))

    def core() -> None:
        for start in range(0, n_scenarios, cfg.chunk_size):
            sl = slice(start, start + cfg.chunk_size)
            inp = MetricInputs.from_batch(batch.take(sl), plan_xy[sl], plan_vxy[sl])
            ttc_1d(inp), rear_ttc_1d(inp), ttc_2d(inp), distances(inp)

    def pet() -> None:
        for start in range(0, n_scenarios, cfg.chunk_size):
            sl = slice(start, start + cfg.chunk_size)
            pet_grid(MetricInputs.from_batch(batch.take(sl), plan_xy[sl], plan_vxy[sl]), cfg.pet_cell_m)

    t_core = _time(core)
    t_pet = _time(pet)
    nr = min(n_reference, n_scenarios)
    small = MetricInputs.from_batch(batch.take(slice(0, nr)), plan_xy[:nr], plan_vxy[:nr])
    t_core_loop = _time(lambda: [_reference_core(small, b) for b in range(nr)])
    npet = max(1, nr // 5)
    t_pet_loop = _time(lambda: [_reference_pet(small, b, cfg.pet_cell_m) for b in range(npet)])
    res = {
        "n_scenarios": float(n_scenarios),
        "full_sps": n_scenarios / t_full,
        "core_sps": n_scenarios / t_core,
        "core_loop_sps": nr / t_core_loop,
        "pet_sps": n_scenarios / t_pet,
        "pet_loop_sps": npet / t_pet_loop,
    }
    res["core_speedup"] = res["core_sps"] / res["core_loop_sps"]
    res["pet_speedup"] = res["pet_sps"] / res["pet_loop_sps"]
    print(f"compute_metrics (all metrics): {res['full_sps']:,.0f} scenarios/s on {n_scenarios:,}")
    print(
        f"TTC front/rear + 2-D TTC + distances: vectorised {res['core_sps']:,.0f}/s, "
        f"loop {res['core_loop_sps']:,.0f}/s (on {nr}), x{res['core_speedup']:,.0f}"
    )
    print(
        f"grid PET: vectorised {res['pet_sps']:,.0f}/s, dict-grid loop {res['pet_loop_sps']:,.1f}/s "
        f"(on {npet}), x{res['pet_speedup']:,.0f}"
    )
    return res


if __name__ == "__main__":
    bench_metrics(int(sys.argv[1]) if len(sys.argv) > 1 else 10_000)
