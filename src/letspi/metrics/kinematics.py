"""Kinematic quality of a planned trajectory: ADE/FDE, accelerations, jerk, lane changes, off-road.

Accelerations and jerk are finite differences at dt over the recorded t = 0 state and the F planned states, so a
plan that starts with a jump is charged for it. x is longitudinal, y lateral (markings are lines y = const).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from letspi.constants import DT_S


@dataclass(frozen=True)
class KinematicsResult:
    """Per-step arrays (B, F, 2) and per-scenario peaks (B,) [m/s^2, m/s^3]."""

    acc_mps2: np.ndarray
    jerk_mps3: np.ndarray
    peak_abs_acc_lon_mps2: np.ndarray
    peak_abs_acc_lat_mps2: np.ndarray
    peak_abs_acc_mps2: np.ndarray
    peak_abs_jerk_mps3: np.ndarray


def ade_fde(plan_xy_m: np.ndarray, truth_xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Average and final displacement error [m], (B,) each, of (B, F, 2) plans against the truth."""
    err = np.hypot(*(plan_xy_m - truth_xy_m).transpose(2, 0, 1))
    return err.mean(axis=1), err[:, -1]


def _nan_peak(x: np.ndarray) -> np.ndarray:
    """max |x| over the last axis; NaN anywhere gives NaN (a non-finite plan has no valid peak)."""
    return np.abs(x).max(axis=-1)


def finite_difference_kinematics(
    plan_vxy_mps: np.ndarray, v0_mps: np.ndarray, a0_mps2: np.ndarray, dt_s: float = DT_S
) -> KinematicsResult:
    """Accelerations and jerk of (B, F, 2) planned velocities from the t = 0 state ``v0_mps``, ``a0_mps2`` (B, 2)."""
    v = np.concatenate([v0_mps[:, None], plan_vxy_mps], axis=1)
    acc = np.diff(v, axis=1) / dt_s
    jerk = np.diff(np.concatenate([a0_mps2[:, None], acc], axis=1), axis=1) / dt_s
    return KinematicsResult(
        acc_mps2=acc,
        jerk_mps3=jerk,
        peak_abs_acc_lon_mps2=_nan_peak(acc[..., 0]),
        peak_abs_acc_lat_mps2=_nan_peak(acc[..., 1]),
        peak_abs_acc_mps2=_nan_peak(np.hypot(acc[..., 0], acc[..., 1])),
        peak_abs_jerk_mps3=_nan_peak(np.hypot(jerk[..., 0], jerk[..., 1])),
    )


def lane_index(y_m: np.ndarray, marking_y_m: np.ndarray) -> np.ndarray:
    """Lane index of lateral positions ``y_m`` (B, F): markings (B, M, ascending, NaN padded) strictly below, minus 1;
    0 = rightmost lane, -1 right of the road or NaN, M - 1 left of it."""
    return (marking_y_m[:, None, :] < y_m[..., None]).sum(axis=-1) - 1


def count_lane_changes(y0_m: np.ndarray, plan_y_m: np.ndarray, marking_y_m: np.ndarray) -> np.ndarray:
    """Number of lane changes (B,) of the planned centre from the lane at t = 0: every step whose lane index differs
    from the previous one counts (a change and back is 2)."""
    lanes = lane_index(np.concatenate([y0_m[:, None], plan_y_m], axis=1), marking_y_m)
    return (np.diff(lanes, axis=1) != 0).sum(axis=1)


def road_edges(marking_y_m: np.ndarray, marking_is_edge: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Right and left road edge y (B,) each: the outermost edge markings (outermost markings if none flagged)."""
    has_edge = marking_is_edge.any(axis=1, keepdims=True)
    use = np.where(has_edge, marking_is_edge, True) & np.isfinite(marking_y_m)
    right = np.where(use, marking_y_m, np.inf).min(axis=1)
    left = np.where(use, marking_y_m, -np.inf).max(axis=1)
    return right, left


def off_road(
    plan_y_m: np.ndarray,
    ego_width_m: np.ndarray,
    marking_y_m: np.ndarray,
    marking_is_edge: np.ndarray,
    tol_m: float = 0.0,
) -> np.ndarray:
    """(B,) bool: at some step the ego box (centres ``plan_y_m`` (B, F), ``ego_width_m`` (B,)) extends more than
    ``tol_m`` beyond a road edge; NaN positions are not flagged here."""
    right, left = road_edges(marking_y_m, marking_is_edge)
    hw = 0.5 * ego_width_m[:, None]
    beyond = (plan_y_m - hw < right[:, None] - tol_m) | (plan_y_m + hw > left[:, None] + tol_m)
    out: np.ndarray = np.any(beyond, axis=1)
    return out
