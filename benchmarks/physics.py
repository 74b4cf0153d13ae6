"""Benchmark: batched social force rollout vs the scalar per-scenario reference loop.

Run ``python -m benchmarks.physics [n_scenarios]``. NumPy's element-wise kernels are
single-threaded, so the batched timing is a one-core number; the thread variables below only stop
BLAS from spreading out should any linear algebra be involved (they must be set before NumPy loads).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.sf_reference import rollout_social_force_reference  # noqa: E402
from letspi.constants import MAX_NEIGHBOURS  # noqa: E402
from letspi.physics.neighbours import predict_constant_velocity  # noqa: E402
from letspi.physics.params import DEFAULT_PARAMS, PARAM_NAMES, PARAM_RANGES, SocialForceParams  # noqa: E402
from letspi.physics.social_force import SocialForceScene, rollout_social_force_scene  # noqa: E402
from letspi.planners.frenet import FrenetPlanner, load_frenet_weights  # noqa: E402
from letspi.scenario.build import VehicleSpec, straight_road_scenario  # noqa: E402
from letspi.scenario.types import ScenarioBatch, concat_batches  # noqa: E402


def synthetic_batch(n_scenarios: int, seed: int = 0, n_distinct: int = 200) -> ScenarioBatch:
    """``n_scenarios`` straight-road scenarios with 8 neighbours each, drawn from ``n_distinct``
    random variations (tiled: building 10k scenarios one by one would dominate the benchmark)."""
    rng = np.random.default_rng(seed)
    parts = []
    for i in range(min(n_distinct, n_scenarios)):
        n_lanes = int(rng.integers(2, 4))
        ego_lane = int(rng.integers(0, n_lanes))
        nbrs = [
            VehicleSpec(
                x0_m=float(rng.uniform(-70.0, 90.0)),
                speed_mps=float(rng.uniform(18.0, 38.0)),
                lane_offset=int(rng.integers(-ego_lane, n_lanes - ego_lane)),
                accel_mps2=float(rng.uniform(-1.0, 0.5)),
                y_offset_m=float(rng.uniform(-0.3, 0.3)),
            )
            for _ in range(MAX_NEIGHBOURS)
        ]
        parts.append(
            straight_road_scenario(
                ego_speed_mps=float(rng.uniform(20.0, 38.0)),
                neighbours=nbrs,
                n_lanes=n_lanes,
                ego_lane_index=ego_lane,
                scenario_id=f"bench{i}",
            )
        )
    distinct = concat_batches(parts)
    return distinct.take(rng.integers(0, len(distinct), n_scenarios))


def random_params(n: int, rng: np.random.Generator) -> SocialForceParams:
    """Parameters drawn uniformly from the lower half of ``PARAM_RANGES`` (plausible values)."""
    cols = []
    for name in PARAM_NAMES:
        lo, hi = PARAM_RANGES[name]
        cols.append(rng.uniform(max(lo, 0.5 * float(getattr(DEFAULT_PARAMS, name))), 0.5 * (lo + hi), n))
    return SocialForceParams.from_matrix(np.stack(cols, axis=1))


def bench_rollout(n_scenarios: int = 10_000, seed: int = 0, n_reference: int = 100) -> dict[str, float]:
    """Time the batched rollout on ``n_scenarios`` and the scalar loop on ``n_reference`` of them.

    Returns scenarios/s for both (the loop's extrapolated from its per-scenario time), their ratio
    and the largest batched-vs-reference position difference on the common subset [m].
    """
    rng = np.random.default_rng(seed)
    batch = synthetic_batch(n_scenarios, seed)
    params = random_params(n_scenarios, rng)
    goals = np.stack(
        [batch.ego_vxy0_mps[:, 0] * 5.0 * rng.uniform(0.8, 1.2, n_scenarios), rng.uniform(-3.75, 3.75, n_scenarios)],
        axis=1,
    ).astype(np.float64)
    prediction = predict_constant_velocity(batch)
    t0 = time.perf_counter()
    scene = SocialForceScene.from_batch(batch, prediction)
    t_scene = time.perf_counter() - t0

    rollout_social_force_scene(scene, params, goals)  # warm-up (page faults, caches)
    t0 = time.perf_counter()
    batched = rollout_social_force_scene(scene, params, goals)
    t_batched = time.perf_counter() - t0

    m = min(n_reference, n_scenarios)
    idx = np.arange(m)
    sub_scene = scene.take(idx)
    sub_params = SocialForceParams.from_matrix(params.as_matrix()[idx])
    t0 = time.perf_counter()
    ref = rollout_social_force_reference(sub_scene, sub_params, goals[idx])
    t_loop = time.perf_counter() - t0

    batched_rate = n_scenarios / t_batched
    loop_rate = m / t_loop
    return {
        "n_scenarios": float(n_scenarios),
        "n_reference": float(m),
        "scene_build_s": t_scene,
        "batched_s": t_batched,
        "batched_scenarios_per_s": batched_rate,
        "loop_scenarios_per_s": loop_rate,
        "speedup": batched_rate / loop_rate,
        "max_abs_diff_m": float(np.abs(batched.xy_m[idx] - ref.xy_m).max()),
    }


def bench_frenet(n_scenarios: int = 1000, seed: int = 0, repeats: int = 3) -> dict[str, float]:
    """CPU and wall time of one batched ``frenet`` plan call per scenario (IDM neighbour prediction and
    the kinematic goal included; the shipped weights), best of ``repeats`` after a warm-up."""
    batch = synthetic_batch(n_scenarios, seed).history()
    planner = FrenetPlanner(settings=FrenetPlanner().settings.model_copy(update={"weights": load_frenet_weights()[0]}),
                            batch_size=n_scenarios)
    planner.plan(batch.take(np.arange(min(32, n_scenarios))))  # warm-up
    cpu, wall = [], []
    for _ in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        plan = planner.plan(batch)
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    return {
        "n_scenarios": float(n_scenarios),
        "cpu_ms_per_scenario": 1e3 * min(cpu) / n_scenarios,
        "wall_ms_per_scenario": 1e3 * min(wall) / n_scenarios,
        "found_safe_pct": 100.0 * float(np.mean(plan.info["found_safe"])),
        "candidates_per_scenario": float(np.mean(planner.lattice(batch.take([0])).pairs.ok.sum())),
    }


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    n = int(args[0]) if args else 10_000
    r = bench_rollout(n)
    print(f"batched: {r['batched_scenarios_per_s']:,.0f} scenarios/s ({n} in {r['batched_s']:.3f} s)")
    print(f"         (+ {r['scene_build_s']:.3f} s to build the scene from (B, N, F, 2) predictions)")
    print(f"loop:    {r['loop_scenarios_per_s']:,.1f} scenarios/s (on {int(r['n_reference'])} scenarios)")
    print(f"speedup: {r['speedup']:,.0f}x; max |batched - loop| = {r['max_abs_diff_m']:.2e} m")


if __name__ == "__main__":
    main()
