"""``sf-opt``: per-scenario search over social-force parameters and goal adjustments ("is the LLM needed?").

Every scenario tries the same grid (repulsion multipliers x longitudinal x lane goal factors around the fitted
parameters) cheapest first against the predicted neighbours and keeps the cheapest candidate safe by the
reflection thresholds (cost: distance from the unadjusted plan), else the best ``fallback_scores``.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace
from typing import Any, Final, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from letspi.constants import N_FUTURE
from letspi.metrics.registry import Metric
from letspi.physics.goals import NEUTRAL_LON_FACTOR, adjust_goals
from letspi.physics.params import SocialForceParams
from letspi.physics.social_force import SocialForceScene, rollout_social_force_scene
from letspi.planners.base import PlanBatch, PlanningContext, PredictingPlanner, Proposals
from letspi.planners.config import SOCIAL_FORCE_OPTIONS, SocialForcePlannerFields
from letspi.planners.options import PlannerOption
from letspi.planners.outputs import LANE_FACTOR, LON_FACTOR, output
from letspi.safety.plan_check import SafetyCheck, check_plans
from letspi.scenario.types import ScenarioBatch

OPTIONS: tuple[PlannerOption[Any], ...] = SOCIAL_FORCE_OPTIONS
OUTPUTS: tuple[Metric, ...] = (
    output("k_scale", "1", "float64", "the chosen candidate's scale of the fitted repulsion gains"),
    LON_FACTOR, LANE_FACTOR,
    output("found_safe", "bool", "bool", "a candidate passed every plan check (else the least unsafe one)"),
    output("n_candidates_tried", "n", "int64", "candidates simulated before the first safe one (27: all)"),
)


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
        """The candidate grid around each scenario's proposed parameters, cheapest first (``staged_search``)."""
        return staged_search(self.space, batch, context, proposals)


#: candidates tried per stage of the staged search, cheapest first; the last stage tries all that are left
SEARCH_STAGES: Final = (1, 2, 6)


def candidate_costs(space: SearchSpace) -> np.ndarray:
    """(C,) each candidate's cost (``space.grid()`` order): how far it moves from the unadjusted plan."""
    k_scale, lon, lane = space.grid().T
    cost: np.ndarray = np.abs(lon - NEUTRAL_LON_FACTOR) + space.lane_change_cost * np.abs(lane) \
        + space.k_scale_cost * (k_scale - 1.0)
    return cost


def search_order(space: SearchSpace) -> np.ndarray:
    """(C,) candidate indices, cheapest first, ties in grid order (the first safe one is the cheapest safe)."""
    cost = candidate_costs(space)
    order: np.ndarray = np.lexsort((np.arange(len(cost)), cost))
    return order


def candidate_rows(space: SearchSpace, batch: ScenarioBatch, goals_xy_m: np.ndarray, proposals: Proposals,
                   rows: np.ndarray, cand: np.ndarray) -> tuple[SocialForceParams, np.ndarray]:
    """Candidate ``cand[r]`` (grid index) of scenario ``rows[r]``: its (clamped) parameters and goal (R, 2)."""
    grid = space.grid()
    k_scale, lon, lane = (grid[cand, i] for i in range(3))
    base = SocialForceParams.from_matrix(proposals.params.as_matrix()[rows])
    params = replace(base, k_np=base.k_np * k_scale, k_nf=base.k_nf * k_scale, k_nl=base.k_nl * k_scale)
    goals = adjust_goals(np.asarray(goals_xy_m)[rows], batch.ego_xy0_m.astype(np.float64)[rows], lon, lane,
                         batch.marking_y_m[rows])
    return params.clamped(), goals


def candidates(space: SearchSpace, batch: ScenarioBatch, goals_xy_m: np.ndarray,
               proposals: Proposals) -> tuple[np.ndarray, SocialForceParams, np.ndarray]:
    """Every scenario's candidate grid, scenario-major: each row's scenario (B C,), parameters and goals (B C, 2)."""
    b, c = len(batch), len(space.grid())
    rep = np.repeat(np.arange(b), c)  # candidate row r belongs to scenario rep[r]
    params, goals = candidate_rows(space, batch, goals_xy_m, proposals, rep, np.tile(np.arange(c), b))
    return rep, params, goals


def fallback_scores(space: SearchSpace, check: SafetyCheck) -> np.ndarray:
    """(R,) the ranking when none is safe (largest wins): no contact, on the road, capped TTC, then gap."""
    ttc = np.minimum(np.minimum(check.min_ttc_s, check.min_rear_ttc_s), space.ttc_cap_s)
    gap = np.nan_to_num(check.min_box_gap_m, nan=-1e9, posinf=1e9)
    out: np.ndarray = -(1e6 * check.collision + 1e3 * check.off_road) + ttc + 0.01 * gap
    return out


def staged_search(space: SearchSpace, batch: ScenarioBatch, context: PlanningContext,
                  proposals: Proposals) -> PlanBatch:
    """Each scenario's plan: stage by stage in ``search_order``, scenarios without a safe candidate yet check the
    stage's candidates; the first safe one wins, else the best ``fallback_scores`` (ties: grid order)."""
    b, grid = len(batch), space.grid()
    pred = context.neighbours
    scene = SocialForceScene.from_batch(batch, pred)  # built once; each stage takes its candidate rows
    order = search_order(space)
    bounds = np.cumsum((0, *SEARCH_STAGES))
    stages = [order[lo:hi] for lo, hi in itertools.pairwise(bounds)] + [order[bounds[-1]:]]
    xy = np.full((b, N_FUTURE, 2), np.nan)
    vxy = np.full((b, N_FUTURE, 2), np.nan)
    goals = np.full((b, 2), np.nan)
    chosen = np.full(b, -1, dtype=np.int64)
    found = np.zeros(b, dtype=bool)
    best_score = np.full(b, -np.inf)
    tried = np.zeros(b, dtype=np.int64)
    pending = np.arange(b)
    for stage in stages:
        if pending.size == 0 or stage.size == 0:
            break
        p, s = len(pending), len(stage)
        rows, cand = np.repeat(pending, s), np.tile(stage, p)
        params, cand_goals = candidate_rows(space, batch, context.goals_xy_m, proposals, rows, cand)
        roll = rollout_social_force_scene(scene.take(rows), params, cand_goals)
        check = check_plans(batch, roll.xy_m, roll.vxy_mps, pred, rows=rows)
        tried[pending] += s
        safe = check.safe(space.ttc_threshold_s, space.gap_threshold_m).reshape(p, s)
        # where nothing is safe yet: the stage's best fallback (NaN ranks first, as argmax takes it),
        # ties to the lowest grid index; it replaces the best so far if better, or equal and earlier in the grid
        score = np.nan_to_num(fallback_scores(space, check), nan=np.inf).reshape(p, s)
        top = score.max(axis=1)
        pick = np.where(score == top[:, None], stage[None, :], len(grid)).argmin(axis=1)
        better = (top > best_score[pending]) | ((top == best_score[pending]) & (stage[pick] < chosen[pending]))
        # a safe candidate ends the search: the first one in the stage (cheapest)
        has_safe = np.asarray(safe.any(axis=1), dtype=bool)
        pick = np.where(has_safe, safe.argmax(axis=1), pick)
        take = has_safe | better
        local = np.flatnonzero(take)
        src = local * s + pick[local]
        dst = pending[local]
        xy[dst], vxy[dst], goals[dst] = roll.xy_m[src], roll.vxy_mps[src], cand_goals[src]
        chosen[dst] = stage[pick[local]]
        best_score[dst] = np.where(has_safe[local], np.inf, top[local])
        found[pending[has_safe]] = True
        pending = pending[~has_safe]
    info = {"k_scale": grid[chosen, 0], "lon_factor": grid[chosen, 1], "lane_factor": grid[chosen, 2],
            "found_safe": found, "n_candidates_tried": tried}
    return PlanBatch(xy_m=xy, vxy_mps=vxy, goals_xy_m=goals, info=info)
