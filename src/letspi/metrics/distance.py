"""Minimum distances between the planned ego and the neighbours (paper "minD").

Two different numbers, both reported:

* ``min_centre_dist_m``: Euclidean distance between box centres. The paper's minD (Table III,
  13-18 m averages) has this magnitude; ``aggregate`` uses it as ``min_dist_m``.
* ``min_box_gap_m``: Euclidean distance between the axis-aligned boxes, i.e.
  hypot(max(|dx| - hx, 0), max(|dy| - hy, 0)) with hx, hy the half-size sums; 0 when the boxes
  touch or overlap. This is the physically meaningful clearance (a rear-end contact has a
  centre distance of about one car length, but a box gap of 0).

Minima are over valid neighbours and the F future steps; +inf (step/nbr -1) with no neighbour.
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
