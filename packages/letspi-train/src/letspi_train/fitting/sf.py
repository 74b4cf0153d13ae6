"""Offline fit of the ``sf`` baseline's fixed parameters (paper: "determined through offline optimization").

On a by-vehicle training split, ``J(θ) = mean ADE [m] + collision_weight x collision rate + low_ttc_weight x
rate of min 1-D TTC < 2 s`` (against the recorded futures), planned as the planner runs. Nelder-Mead over
the seven parameters, clamped to ``TYPICAL_RANGES``: unbounded, ADE alone switches repulsion off.
Deterministic for a seed.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from letspi.metrics.collision import boxes_overlap
from letspi.metrics.inputs import MetricInputs
from letspi.metrics.kinematics import ade_fde
from letspi.metrics.ttc import ttc_1d
from letspi.physics.goals import KinematicGoalPredictor
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.params import (
    DEFAULT_PARAMS,
    PARAM_NAMES,
    TYPICAL_RANGES,
    SocialForceParams,
)
from letspi.physics.social_force import rollout_social_force
from letspi.scenario.split import split_by_vehicle, subsample
from letspi.scenario.types import ScenarioBatch


@dataclass(frozen=True)
class FitResult:
    params: SocialForceParams
    train_objective: float
    train_ade_m: float
    train_collision_pct: float
    validation_ade_m: float
    validation_collision_pct: float
    start_objective: float
    n_evaluations: int
    seconds: float


class _Objective:
    def __init__(self, batch: ScenarioBatch, collision_weight: float, low_ttc_weight: float) -> None:
        self.batch = batch
        self.goals = KinematicGoalPredictor().predict_goals(batch).top
        self.pred = predict_neighbours(batch, NeighbourPredictionMode.IDM)
        self.truth = batch.ego_xy_m[:, batch.future_slice].astype(np.float64)
        self.weight = collision_weight
        self.low_ttc_weight = low_ttc_weight

    def scores(self, params: SocialForceParams) -> tuple[float, float, float]:
        b = self.batch
        roll = rollout_social_force(b, params.broadcast(len(b)), self.goals, self.pred)
        ade, _ = ade_fde(roll.xy_m, self.truth)
        inp = MetricInputs.from_batch(b, roll.xy_m, roll.vxy_mps)
        collided = boxes_overlap(inp).any(axis=(1, 2))
        low_ttc = ttc_1d(inp).min_ttc_s < LOW_TTC_S
        ade_mean = float(np.nanmean(ade))
        rate = float(collided.mean())
        return ade_mean + self.weight * rate + self.low_ttc_weight * float(low_ttc.mean()), ade_mean, 100.0 * rate


LOW_TTC_S = 2.0


def _bounds() -> tuple[np.ndarray, np.ndarray]:
    lo = np.array([TYPICAL_RANGES[n][0] for n in PARAM_NAMES])
    hi = np.array([TYPICAL_RANGES[n][1] for n in PARAM_NAMES])
    return lo, hi


def _to_params(z: np.ndarray) -> SocialForceParams:
    lo, hi = _bounds()
    return SocialForceParams.from_mapping(dict(zip(PARAM_NAMES, np.clip(lo + z * (hi - lo), lo, hi), strict=True)))


def _to_unit(p: SocialForceParams) -> np.ndarray:
    lo, hi = _bounds()
    return (p.as_array() - lo) / (hi - lo)


def fit_sf_params(
    batch: ScenarioBatch,
    *,
    seed: int = 0,
    train_fraction: float = 0.7,
    max_train: int | None = 2000,
    max_evaluations: int = 200,
    collision_weight: float = 50.0,
    low_ttc_weight: float = 5.0,
    progress: Callable[[int], None] | None = None,
) -> FitResult:
    """Fit the fixed SF parameters on the training split of ``batch``."""
    train_idx, val_idx = split_by_vehicle(batch, train_fraction, seed)
    train_idx = subsample(train_idx, max_train, np.random.default_rng(seed))
    train = _Objective(batch.take(train_idx), collision_weight, low_ttc_weight)
    t0 = time.perf_counter()
    n_eval = 0

    def f(z: np.ndarray) -> float:
        nonlocal n_eval
        n_eval += 1
        if progress is not None:
            progress(1)
        return train.scores(_to_params(z))[0]

    start = np.clip(_to_unit(DEFAULT_PARAMS), 0.0, 1.0)
    start_obj = f(start)
    res = minimize(f, start, method="Nelder-Mead",
                   options={"maxfev": max_evaluations, "xatol": 1e-3, "fatol": 1e-3})
    best = _to_params(res.x) if res.fun <= start_obj else DEFAULT_PARAMS
    obj, ade, cr = train.scores(best)
    if len(val_idx):
        _, v_ade, v_cr = _Objective(batch.take(val_idx), collision_weight, low_ttc_weight).scores(best)
    else:
        v_ade, v_cr = float("nan"), float("nan")
    return FitResult(best, obj, ade, cr, v_ade, v_cr, start_obj, n_eval, time.perf_counter() - t0)
