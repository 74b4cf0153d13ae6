"""``sf-opt``: per-scenario search over social-force parameters and goal adjustments.

The reviewer's baseline for "is the LLM needed?": every scenario tries the same candidate set
(repulsion strength multipliers × longitudinal goal factors × lane factors around the fitted
parameters), simulates each against the *predicted* neighbours (never the ground truth), and keeps

1. among candidates that are safe by the reflection thresholds (no contact, on the road,
   front and rear TTC ≥ 1.5 s, in-path gap ≥ 2 m to the predicted neighbours; see
   ``letspi.safety.plan_check``), the one closest to the unadjusted plan (cost: |lon − neutral| +
   lane-change penalty × |lane| + repulsion penalty);
2. if none is safe, the one with the largest min(TTC, cap) and then box gap.

All candidates of a batch are rolled out in one vectorised call (B × C scenarios).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from letspi.physics.goals import NEUTRAL_LON_FACTOR, adjust_goals
from letspi.physics.params import SocialForceParams
from letspi.physics.social_force import SocialForceScene, rollout_social_force_scene
from letspi.physics.types import RolloutResult
from letspi.planners.base import PlanBatch, PlanningContext, PredictingPlanner, Proposals
from letspi.planners.config import SOCIAL_FORCE_OPTIONS, SocialForcePlannerFields
from letspi.planners.options import PlannerOption
from letspi.safety.plan_check import SafetyCheck, check_plans
from letspi.scenario.types import ScenarioBatch

OPTIONS: tuple[PlannerOption[Any], ...] = SOCIAL_FORCE_OPTIONS


class SearchSpace(BaseModel):
    """Candidate grid; the product of the three axes is tried for every scenario."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    k_scale: tuple[float, ...] = (1.0, 1.6, 2.5)  # multiplies k_np, k_nf and k_nl together
    lon_factor: tuple[float, ...] = (NEUTRAL_LON_FACTOR, 0.7, 1.0)
    lane_factor: tuple[float, ...] = (0.0, -1.0, 1.0)
    ttc_threshold_s: float = 1.5
    gap_threshold_m: float = 2.0
    ttc_cap_s: float = 10.0
    lane_change_cost: float = 2.0
    k_scale_cost: float = 0.2

    def grid(self) -> np.ndarray:
        """(C, 3) rows of (k_scale, lon_factor, lane_factor), the neutral candidate first."""
        mesh = np.meshgrid(self.k_scale, self.lon_factor, self.lane_factor, indexing="ij")
        return np.stack([m.reshape(-1) for m in mesh], axis=1)


class SfOptConfig(SocialForcePlannerFields):
    kind: Literal["sf-opt"] = "sf-opt"
    search: SearchSpace = Field(default_factory=SearchSpace)


@dataclass
class SocialForceSearchPlanner(PredictingPlanner):
    params: SocialForceParams
    space: SearchSpace = field(default_factory=SearchSpace)
    name: str = "sf-opt"
    batch_size: int = 256

    def propose(self, batch: ScenarioBatch, context: PlanningContext) -> Proposals:
        """The fitted parameters: the centre of every scenario's search (the search is physics)."""
        b = len(batch)
        return Proposals(self.params.broadcast(b), np.full(b, NEUTRAL_LON_FACTOR), np.zeros(b))

    def simulate(self, batch: ScenarioBatch, context: PlanningContext, proposals: Proposals) -> PlanBatch:
        """The candidate grid around each scenario's proposed parameters, rolled out and checked at once."""
        pred = context.neighbours
        rep, params, cand_goals = candidates(self.space, batch, context.goals_xy_m, proposals)
        # the scene (per-scenario arrays) is built once and repeated per candidate, not the whole batch
        scene = SocialForceScene.from_batch(batch, pred).take(rep)
        roll = rollout_social_force_scene(scene, params, cand_goals)
        check = check_plans(batch, roll.xy_m, roll.vxy_mps, pred, rows=rep)
        return choose_candidates(self.space, len(batch), roll, cand_goals, check)


def candidates(space: SearchSpace, batch: ScenarioBatch, goals_xy_m: np.ndarray,
               proposals: Proposals) -> tuple[np.ndarray, SocialForceParams, np.ndarray]:
    """Every scenario's candidate grid, scenario-major: the scenario of each candidate row (B C,), their
    (clamped) social force parameters and their goals (B C, 2)."""
    b = len(batch)
    grid = space.grid()
    rep = np.repeat(np.arange(b), len(grid))  # candidate row r belongs to scenario rep[r]
    k_scale, lon, lane = (np.tile(grid[:, i], b) for i in range(3))
    base = SocialForceParams.from_matrix(proposals.params.as_matrix()[rep])
    params = replace(base, k_np=base.k_np * k_scale, k_nf=base.k_nf * k_scale, k_nl=base.k_nl * k_scale)
    goals = adjust_goals(np.asarray(goals_xy_m)[rep], batch.ego_xy0_m.astype(np.float64)[rep], lon, lane,
                         batch.marking_y_m[rep])
    return rep, params.clamped(), goals


def choose_candidates(space: SearchSpace, b: int, roll: RolloutResult, cand_goals: np.ndarray,
                      check: SafetyCheck) -> PlanBatch:
    """The plan of each of ``b`` scenarios from its C candidates (rows scenario-major, ``space.grid()``
    order): the cheapest safe one, else the best ranked (module docstring)."""
    grid = space.grid()
    c = len(grid)
    k_scale, lon, lane = (np.tile(grid[:, i], b) for i in range(3))
    safe = check.safe(space.ttc_threshold_s, space.gap_threshold_m).reshape(b, c)
    cost = (
        np.abs(lon - NEUTRAL_LON_FACTOR)
        + space.lane_change_cost * np.abs(lane)
        + space.k_scale_cost * (k_scale - 1.0)
    ).reshape(b, c)
    # fallback ranking when nothing is safe: larger capped TTC, then larger gap, no contact first
    ttc = np.minimum(np.minimum(check.min_ttc_s, check.min_rear_ttc_s), space.ttc_cap_s).reshape(b, c)
    gap = np.nan_to_num(check.min_box_gap_m, nan=-1e9, posinf=1e9).reshape(b, c)
    unsafe_score = -(1e6 * check.collision.reshape(b, c) + 1e3 * check.off_road.reshape(b, c)) + ttc + 0.01 * gap
    best = np.where(safe.any(axis=1), np.argmin(np.where(safe, cost, np.inf), axis=1),
                    np.argmax(unsafe_score, axis=1))
    rows = np.arange(b) * c + best
    info = {
        "k_scale": k_scale[rows], "lon_factor": lon[rows], "lane_factor": lane[rows],
        "found_safe": safe.any(axis=1), "n_safe_candidates": safe.sum(axis=1),
    }
    return PlanBatch(xy_m=roll.xy_m[rows], vxy_mps=roll.vxy_mps[rows], goals_xy_m=cand_goals[rows], info=info)
