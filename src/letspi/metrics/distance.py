"""Minimum distances between the planned ego and the neighbours (paper "minD"), over valid neighbours and steps.

``min_centre_dist_m``: between box centres, the paper's minD magnitude (``min_dist_m`` in ``aggregate``).
``min_box_gap_m``: between the boxes, hypot(max(|dx| - hx, 0), max(|dy| - hy, 0)) with half-size sums hx, hy;
0 on contact: the clearance. +inf (step/nbr -1) without a neighbour.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from letspi.metrics.inputs import MetricInputs, min_over_nbr_time


@dataclass(frozen=True)
class DistanceResult:
    """Per-pair arrays (B, N, F) and per-scenario minima (B,) with their step / neighbour slot."""

    centre_dist_m: np.ndarray
    box_gap_m: np.ndarray
    min_centre_dist_m: np.ndarray
    min_centre_dist_step: np.ndarray
    min_centre_dist_nbr: np.ndarray
    min_box_gap_m: np.ndarray
    min_gap_step: np.ndarray
    min_gap_nbr: np.ndarray


def box_gap(dx: np.ndarray, dy: np.ndarray, hx: np.ndarray, hy: np.ndarray) -> np.ndarray:
    """Euclidean gap [m] between axis-aligned boxes (0 when overlapping), broadcasting."""
    gx = np.maximum(np.abs(dx) - hx, 0.0)
    gy = np.maximum(np.abs(dy) - hy, 0.0)
    return np.hypot(gx, gy)


def box_gaps(inp: MetricInputs) -> np.ndarray:
    """Box gap [m] to every neighbour, (B, N, F); NaN where invalid."""
    return box_gap(inp.dx_m, inp.dy_m, inp.half_len_sum_m, inp.half_wid_sum_m)


def distances(inp: MetricInputs) -> DistanceResult:
    """Centre distance and box gap to every valid neighbour and their per-scenario minima."""
    centre = np.hypot(inp.dx_m, inp.dy_m)  # NaN where invalid -> ignored by the minimum
    gap = box_gaps(inp)
    c_val, c_step, c_nbr = min_over_nbr_time(centre)
    g_val, g_step, g_nbr = min_over_nbr_time(gap)
    return DistanceResult(
        centre_dist_m=centre,
        box_gap_m=gap,
        min_centre_dist_m=c_val,
        min_centre_dist_step=c_step,
        min_centre_dist_nbr=c_nbr,
        min_box_gap_m=g_val,
        min_gap_step=g_step,
        min_gap_nbr=g_nbr,
    )
