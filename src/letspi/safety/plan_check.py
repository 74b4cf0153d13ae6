"""Safety of candidate plans against *predicted* neighbours (what a planner may know at t = 0), for ``sf-opt`` and
LetsPi's reflection; the evaluation scores the chosen plan against the ground-truth futures instead."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from letspi.metrics.collision import boxes_overlap
from letspi.metrics.distance import box_gaps
from letspi.metrics.inputs import MetricInputs, min_over_nbr_time
from letspi.metrics.kinematics import off_road
from letspi.metrics.ttc import rear_ttc_1d, ttc_1d
from letspi.physics.types import NeighbourPrediction
from letspi.scenario.types import ScenarioBatch


@dataclass(frozen=True)
class SafetyCheck:
    """(B,) each; steps and slots -1 for none. ``min_ttc_s`` / ``min_rear_ttc_s``: 1-D TTC with the vehicle ahead /
    behind in the ego's path (+inf if none closes in); ``min_path_gap_m``: smallest bumper gap to a vehicle in the
    ego's path (lateral box overlap), ahead or behind: a "distance < 2 m" that ignores adjacent-lane passes."""

    min_ttc_s: np.ndarray
    min_ttc_step: np.ndarray
    min_ttc_nbr: np.ndarray
    min_rear_ttc_s: np.ndarray
    min_rear_ttc_step: np.ndarray
    min_rear_ttc_nbr: np.ndarray
    min_box_gap_m: np.ndarray
    min_gap_step: np.ndarray
    min_gap_nbr: np.ndarray
    min_path_gap_m: np.ndarray
    collision: np.ndarray
    off_road: np.ndarray

    def safe(self, ttc_threshold_s: float, gap_threshold_m: float) -> np.ndarray:
        """(B,) bool: no contact, on the road, front and rear TTC and in-path gap above thresholds."""
        return (~self.collision & ~self.off_road & (self.min_ttc_s >= ttc_threshold_s)
                & (self.min_rear_ttc_s >= ttc_threshold_s) & (self.min_path_gap_m >= gap_threshold_m))


def predicted_inputs(
    batch: ScenarioBatch, plan_xy_m: np.ndarray, plan_vxy_mps: np.ndarray, neighbours: NeighbourPrediction,
    rows: np.ndarray | None = None,
) -> MetricInputs:
    """Metric inputs pairing plans (P, F, 2) with predicted neighbour futures (B, N, F, 2); ``rows`` (P,): the scenario
    of each plan (candidates of one scenario share its neighbours), None: one plan per scenario."""
    def per_plan(a: np.ndarray) -> np.ndarray:
        return a if rows is None else a[rows]

    nxy = np.asarray(neighbours.xy_m, dtype=np.float64)
    return MetricInputs(
        ego_xy_m=np.asarray(plan_xy_m, dtype=np.float64),
        ego_vxy_mps=np.asarray(plan_vxy_mps, dtype=np.float64),
        ego_length_m=per_plan(batch.ego_length_m.astype(np.float64)),
        ego_width_m=per_plan(batch.ego_width_m.astype(np.float64)),
        nbr_xy_m=per_plan(nxy),
        nbr_vxy_mps=per_plan(np.asarray(neighbours.vxy_mps, dtype=np.float64)),
        nbr_valid=per_plan(np.asarray(neighbours.valid, dtype=bool) & np.isfinite(nxy).all(axis=-1)),
        nbr_length_m=per_plan(batch.nbr_length_m.astype(np.float64)),
        nbr_width_m=per_plan(batch.nbr_width_m.astype(np.float64)),
    )


def min_path_gap_m(inp: MetricInputs) -> np.ndarray:
    lon_gap = np.abs(inp.dx_m) - inp.half_len_sum_m
    in_path = inp.lateral_overlap & inp.nbr_valid
    return np.where(in_path, lon_gap, np.inf).min(axis=(1, 2))


def check_plans(
    batch: ScenarioBatch, plan_xy_m: np.ndarray, plan_vxy_mps: np.ndarray, neighbours: NeighbourPrediction,
    rows: np.ndarray | None = None,
) -> SafetyCheck:
    """TTC, box gap, contact and road-edge checks of plans against predicted neighbours (``rows``: the
    scenario of each plan, as ``predicted_inputs``)."""
    inp = predicted_inputs(batch, plan_xy_m, plan_vxy_mps, neighbours, rows)
    return _checks(inp, *(m if rows is None else m[rows] for m in (batch.marking_y_m, batch.marking_is_edge)))


def check_recorded(batch: ScenarioBatch, plan_xy_m: np.ndarray, plan_vxy_mps: np.ndarray) -> SafetyCheck:
    """The same checks against the RECORDED future (neighbours and context vehicles, as the evaluation
    scores them): hindsight for training labels only, never for planning. ``batch`` must hold the future."""
    return check_inputs(batch, MetricInputs.from_batch(batch, plan_xy_m, plan_vxy_mps))


def check_inputs(batch: ScenarioBatch, inp: MetricInputs) -> SafetyCheck:
    """The checks of ``check_plans`` on prepared metric inputs (any neighbour slots)."""
    return _checks(inp, batch.marking_y_m, batch.marking_is_edge)


def _checks(inp: MetricInputs, marking_y_m: np.ndarray, marking_is_edge: np.ndarray) -> SafetyCheck:
    # the rear TTC is the front TTC of the scene mirrored in x; computed on the same relative geometry
    ttc = ttc_1d(inp)
    rear = rear_ttc_1d(inp)
    gap_m, gap_step, gap_nbr = min_over_nbr_time(box_gaps(inp))
    contact = np.asarray(boxes_overlap(inp).any(axis=(1, 2)), dtype=bool)
    leaves_road = off_road(inp.ego_xy_m[..., 1], inp.ego_width_m, marking_y_m, marking_is_edge)
    return SafetyCheck(
        min_ttc_s=ttc.min_ttc_s, min_ttc_step=ttc.min_ttc_step, min_ttc_nbr=ttc.min_ttc_nbr,
        min_rear_ttc_s=rear.min_ttc_s, min_rear_ttc_step=rear.min_ttc_step, min_rear_ttc_nbr=rear.min_ttc_nbr,
        min_box_gap_m=gap_m, min_gap_step=gap_step, min_gap_nbr=gap_nbr, min_path_gap_m=min_path_gap_m(inp),
        collision=contact, off_road=leaves_road)
