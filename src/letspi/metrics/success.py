"""Success of a plan (paper "SR", not defined precisely there; REFERENCE §5).

A plan succeeds when all of these hold (tolerances in ``MetricsConfig``):

1. finite: every planned position and velocity is a finite number;
2. feasible: peak |a_lon| <= ``max_abs_acc_lon_mps2`` (8 m/s^2: about the braking limit of a car)
   and peak |a_lat| <= ``max_abs_acc_lat_mps2`` (4 m/s^2: well above highway lane-change levels),
   from ``letspi.metrics.kinematics`` (including the step from the t = 0 state);
3. on the road: ``off_road`` is False;
4. goal reached: the final planned centre is within ``goal_tol_lon_m`` (5 m) along x and
   ``goal_tol_lat_m`` (1 m) along y of the goal; when no goal is given this test is skipped;
5. no collision: no box overlap (and, if ``success_requires_no_collision_2m``, no 2 m variant).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from letspi.metrics.config import MetricsConfig


@dataclass(frozen=True)
class SuccessResult:
    """(B,) bool each: the five criteria and their conjunction ``success``."""

    finite: np.ndarray
    feasible: np.ndarray
    on_road: np.ndarray
    goal_reached: np.ndarray
    no_collision: np.ndarray
    success: np.ndarray


def success(
    plan_xy_m: np.ndarray,
    plan_vxy_mps: np.ndarray,
    peak_abs_acc_lon_mps2: np.ndarray,
    peak_abs_acc_lat_mps2: np.ndarray,
    off_road: np.ndarray,
    collision: np.ndarray,
    collision_2m: np.ndarray,
    goals_xy_m: np.ndarray | None,
    config: MetricsConfig,
) -> SuccessResult:
    """Evaluate the success criteria (module doc). Arrays are (B, F, 2) plans and (B,) flags/peaks."""
    b = plan_xy_m.shape[0]
    finite = np.isfinite(plan_xy_m).all(axis=(1, 2)) & np.isfinite(plan_vxy_mps).all(axis=(1, 2))
    # NaN peaks compare False, so a non-finite plan is never feasible
    feasible = (peak_abs_acc_lon_mps2 <= config.max_abs_acc_lon_mps2) & (
        peak_abs_acc_lat_mps2 <= config.max_abs_acc_lat_mps2
    )
    if goals_xy_m is None:
        goal = np.ones(b, dtype=bool)
    else:
        err = np.abs(plan_xy_m[:, -1] - np.asarray(goals_xy_m, dtype=np.float64))
        goal = (err[:, 0] <= config.goal_tol_lon_m) & (err[:, 1] <= config.goal_tol_lat_m)
    no_coll = ~collision
    if config.success_requires_no_collision_2m:
        no_coll = no_coll & ~collision_2m
    on_road = ~off_road
    return SuccessResult(
        finite=finite,
        feasible=feasible,
        on_road=on_road,
        goal_reached=goal,
        no_collision=no_coll,
        success=finite & feasible & on_road & goal & no_coll,
    )
