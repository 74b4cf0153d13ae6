"""Success of a plan (paper "SR", which the paper does not define precisely), tolerances in ``MetricsConfig``.

``success``: 1. every planned position and velocity is finite; 2. peak |a_lon| <= ``max_abs_acc_lon_mps2`` and
|a_lat| <= ``max_abs_acc_lat_mps2`` (``kinematics``, including the step from t = 0); 3. not ``off_road``;
4. ``reference_reached``: the final centre is in the recorded human's final lane or within ``sr_lat_tol_m`` of it
laterally, and its progress x(5 s) - x(0) is within max(``sr_progress_tol_m``, ``sr_progress_tol_rel`` · the
human's) of the human's; 5. no box overlap (nor a 2 m variant if ``success_requires_no_collision_2m``).

The planner's own goal is not the reference (planners that return their own endpoint would pass by
construction): ``goal_reached`` (final centre within ``goal_tol_lon_m`` / ``goal_tol_lat_m`` of the goal; True
without one) and ``success_self`` (criteria 1, 2, 3, 5 and ``goal_reached``) keep that test apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from letspi.metrics.config import MetricsConfig
from letspi.metrics.kinematics import lane_index


@dataclass(frozen=True)
class SuccessResult:
    """(B,) bool each: the criteria and their conjunctions ``success`` and ``success_self``."""

    finite: np.ndarray
    feasible: np.ndarray
    on_road: np.ndarray
    reference_reached: np.ndarray
    goal_reached: np.ndarray
    no_collision: np.ndarray
    success: np.ndarray
    success_self: np.ndarray


def reference_reached(
    plan_end_xy_m: np.ndarray,
    human_end_xy_m: np.ndarray,
    start_x_m: np.ndarray,
    marking_y_m: np.ndarray,
    config: MetricsConfig,
) -> np.ndarray:
    """(B,) bool: the plan ends in the human's final lane with the human's progress (module docstring).
    ``plan_end_xy_m``, ``human_end_xy_m`` (B, 2); ``start_x_m`` (B,); ``marking_y_m`` (B, M). NaN plans give False."""
    plan_lane = lane_index(plan_end_xy_m[:, 1:2], marking_y_m)[:, 0]
    human_lane = lane_index(human_end_xy_m[:, 1:2], marking_y_m)[:, 0]
    lat_ok = (plan_lane == human_lane) & np.isfinite(plan_end_xy_m[:, 1])
    lat_ok |= np.abs(plan_end_xy_m[:, 1] - human_end_xy_m[:, 1]) <= config.sr_lat_tol_m
    human_progress = human_end_xy_m[:, 0] - start_x_m
    tol = np.maximum(config.sr_progress_tol_m, config.sr_progress_tol_rel * np.abs(human_progress))
    lon_ok = np.abs(plan_end_xy_m[:, 0] - human_end_xy_m[:, 0]) <= tol  # False for NaN
    out: np.ndarray = lat_ok & lon_ok
    return out


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
    *,
    human_end_xy_m: np.ndarray,
    start_x_m: np.ndarray,
    marking_y_m: np.ndarray,
) -> SuccessResult:
    """Evaluate the success criteria (module docstring): ``plan_xy_m``, ``plan_vxy_mps`` (B, F, 2); peaks and flags
    (B,); ``goals_xy_m`` (B, 2) or None; ``human_end_xy_m`` (B, 2); ``start_x_m`` (B,); ``marking_y_m`` (B, M)."""
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
    ref = reference_reached(plan_xy_m[:, -1], human_end_xy_m, start_x_m, marking_y_m, config)
    no_coll = ~collision
    if config.success_requires_no_collision_2m:
        no_coll = no_coll & ~collision_2m
    on_road = ~off_road
    common = finite & feasible & on_road & no_coll
    return SuccessResult(
        finite=finite,
        feasible=feasible,
        on_road=on_road,
        reference_reached=ref,
        goal_reached=goal,
        no_collision=no_coll,
        success=common & ref,
        success_self=common & goal,
    )
