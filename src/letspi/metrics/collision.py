"""Collision tests (paper "CR").

``collision``: the boxes of the planned ego and a valid neighbour overlap (touching is not) at some future step:
real contact. ``collision_2m``: the paper's "distance < 2.0 m", which it does not define. Default
``mode="longitudinal_gap"``: overlap, or a neighbour in the ego's path (boxes overlapping laterally) less than
``threshold_m`` bumper to bumper ahead or behind; ``"centre_distance"`` and ``"box_gap"`` are the two literal
readings (``MetricsConfig.collision_2m_m`` / ``collision_2m_mode``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from letspi.metrics.config import Collision2mMode
from letspi.metrics.distance import box_gap
from letspi.metrics.inputs import MetricInputs


@dataclass(frozen=True)
class CollisionResult:
    """(B,) each: flags, and the first step / neighbour slot of the event (-1 when none);
    ``overlap`` (B, N, F): the box overlap per pair and step (input of ``letspi.metrics.fault``)."""

    collision: np.ndarray
    collision_step: np.ndarray
    collision_nbr: np.ndarray
    collision_2m: np.ndarray
    collision_2m_step: np.ndarray
    collision_2m_nbr: np.ndarray
    overlap: np.ndarray


def boxes_overlap(inp: MetricInputs) -> np.ndarray:
    """(B, N, F) bool: ego and neighbour boxes overlap (strictly) at that step."""
    return inp.lateral_overlap & inp.longitudinal_overlap


def _first_event(event: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flag, first step and lowest neighbour slot at that step of a (B, N, F) event array."""
    per_step = np.any(event, axis=1)  # (B, F)
    flag: np.ndarray = np.any(per_step, axis=1)
    step = np.where(flag, per_step.argmax(axis=1), -1)
    at_step = np.take_along_axis(event, np.maximum(step, 0)[:, None, None], axis=2)[:, :, 0]  # (B, N)
    nbr = np.where(flag, at_step.argmax(axis=1), -1)
    return flag, step, nbr


def near_collision(inp: MetricInputs, threshold_m: float, mode: Collision2mMode) -> np.ndarray:
    """(B, N, F) bool for the "distance < threshold" variant (readings: module doc)."""
    if mode == "centre_distance":
        return np.hypot(inp.dx_m, inp.dy_m) < threshold_m
    if mode == "box_gap":
        return box_gap(inp.dx_m, inp.dy_m, inp.half_len_sum_m, inp.half_wid_sum_m) < threshold_m
    if mode == "longitudinal_gap":
        lon_gap = np.abs(inp.dx_m) - inp.half_len_sum_m
        return inp.lateral_overlap & (lon_gap < threshold_m)
    raise ValueError(f"unknown collision_2m mode {mode!r}")


def collisions(
    inp: MetricInputs, threshold_m: float = 2.0, mode: Collision2mMode = "longitudinal_gap"
) -> CollisionResult:
    """Primary box-overlap collision and the 2 m variant, with the first step and neighbour."""
    overlap = boxes_overlap(inp)
    c, c_step, c_nbr = _first_event(overlap)
    n, n_step, n_nbr = _first_event(near_collision(inp, threshold_m, mode) | overlap)
    return CollisionResult(
        collision=c,
        collision_step=c_step,
        collision_nbr=c_nbr,
        collision_2m=n,
        collision_2m_step=n_step,
        collision_2m_nbr=n_nbr,
        overlap=overlap,
    )
