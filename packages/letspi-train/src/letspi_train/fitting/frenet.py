"""Offline choice of the ``frenet`` planner's cost weights (``letspi fit frenet``) on training traffic.

Split by ego vehicle; the planner runs as evaluated. Objective on the training part: ``J(w) = mean ADE [m]
+ collision_weight x at-fault collision rate + low_ttc_weight x low-TTC rate + failure_weight x (1 - success
rate)``. The lattice is built once (only the choice depends on w); J is piecewise constant in w, so the
search is coordinate descent over a log-spaced ``grid`` per weight, ``k_speed`` fixed at 1. Deterministic.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from letspi.metrics.compute import compute_metrics
from letspi.physics.goals import GoalPredictor
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.planners.frenet import (
    WEIGHT_NAMES,
    FrenetSettings,
    FrenetWeights,
    Lattice,
    build_lattice,
    plan_from_lattice,
)
from letspi.scenario.split import split_by_vehicle, subsample
from letspi.scenario.types import ScenarioBatch

#: weights searched (k_speed is the unit) and their grid (log-spaced)
SEARCHED: tuple[str, ...] = ("k_jerk_lon", "k_jerk_lat", "k_time", "k_offset", "k_goal_lane", "k_headway", "k_rss")
DEFAULT_GRID: tuple[float, ...] = (0.0, 0.001, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0)


@dataclass(frozen=True)
class Scores:
    objective: float
    ade_m: float
    cr_at_fault_pct: float
    cr_pct: float
    low_ttc_pct: float
    sr_pct: float

    def as_dict(self) -> dict[str, float]:
        return dict(self.__dict__)


@dataclass(frozen=True)
class FrenetFitResult:
    weights: FrenetWeights
    start: Scores
    train: Scores
    validation: Scores
    validation_start: Scores
    n_train: int
    n_validation: int
    n_evaluations: int
    seconds: float
    trace: list[dict[str, float]]


class _Objective:
    def __init__(self, batch: ScenarioBatch, lattice: Lattice, collision_weight: float, low_ttc_weight: float,
                 failure_weight: float) -> None:
        self.batch, self.lattice = batch, lattice
        self.weights = (collision_weight, low_ttc_weight, failure_weight)

    def scores(self, w: FrenetWeights) -> Scores:
        plan = plan_from_lattice(self.lattice, w)
        m = compute_metrics(self.batch, plan.xy_m, plan.vxy_mps, plan.goals_xy_m)
        ade = float(np.nanmean(m.ade_m))
        fault = float(np.mean(m.collision_at_fault))
        low = float(np.mean(m.low_ttc))
        sr = float(np.mean(m.success))
        cw, lw, fw = self.weights
        return Scores(ade + cw * fault + lw * low + fw * (1.0 - sr), ade, 100.0 * fault,
                      100.0 * float(np.mean(m.collision)), 100.0 * low, 100.0 * sr)


def lattice_of(batch: ScenarioBatch, goal_predictor: GoalPredictor, settings: FrenetSettings,
               neighbour_mode: NeighbourPredictionMode = NeighbourPredictionMode.IDM) -> Lattice:
    """The planner's lattice for ``batch`` (its history only, as the harness shows it)."""
    seen = batch.history()
    goals = goal_predictor.predict_goals(seen).top
    return build_lattice(seen, predict_neighbours(seen, neighbour_mode), goals, settings)


def fit_frenet_weights(
    batch: ScenarioBatch,
    goal_predictor: GoalPredictor,
    *,
    settings: FrenetSettings | None = None,
    seed: int = 0,
    train_fraction: float = 0.7,
    max_train: int | None = 4000,
    rounds: int = 2,
    grid: tuple[float, ...] = DEFAULT_GRID,
    collision_weight: float = 50.0,
    low_ttc_weight: float = 5.0,
    failure_weight: float = 5.0,
    progress: Callable[[str], None] | None = None,
) -> FrenetFitResult:
    """Choose the cost weights on the training vehicles of ``batch``; report them on the held-out ones."""
    settings = settings or FrenetSettings()
    t0 = time.perf_counter()
    train_idx, val_idx = split_by_vehicle(batch, train_fraction, seed)
    train_idx = subsample(train_idx, max_train, np.random.default_rng(seed))
    train_batch = batch.take(train_idx)
    train = _Objective(train_batch, lattice_of(train_batch, goal_predictor, settings), collision_weight,
                       low_ttc_weight, failure_weight)
    seen: dict[tuple[float, ...], Scores] = {}
    trace: list[dict[str, float]] = []

    def evaluate(w: FrenetWeights) -> Scores:
        key = tuple(getattr(w, n) for n in WEIGHT_NAMES)
        if key not in seen:
            seen[key] = train.scores(w)
            trace.append({**w.model_dump(), **seen[key].as_dict()})
            if progress is not None:
                progress(f"{len(seen)}: {w.model_dump()} -> J {seen[key].objective:.4f}")
        return seen[key]

    start_w = settings.weights.model_copy(update={"k_speed": 1.0})
    start = best_score = evaluate(start_w)
    best = start_w
    for _ in range(rounds):
        improved = False
        for name in SEARCHED:
            for value in grid:
                cand = best.model_copy(update={name: float(value)})
                sc = evaluate(cand)
                if sc.objective < best_score.objective - 1e-12:
                    best, best_score, improved = cand, sc, True
        if not improved:
            break
    if len(val_idx):
        val_batch = batch.take(val_idx)
        val = _Objective(val_batch, lattice_of(val_batch, goal_predictor, settings), collision_weight,
                         low_ttc_weight, failure_weight)
        validation, validation_start = val.scores(best), val.scores(start_w)
    else:
        nan = Scores(*(float("nan"),) * 6)
        validation = validation_start = nan
    return FrenetFitResult(best, start, best_score, validation, validation_start, len(train_idx), len(val_idx),
                           len(seen), time.perf_counter() - t0, trace)
