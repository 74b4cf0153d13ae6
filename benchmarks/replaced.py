"""The algorithms issue 27's speed work replaced, kept as the reference the new ones are measured and
checked against (``python -m benchmarks.speed physics``: the ratio; tests/test_perf_equivalence.py: bit-identical
results). Each computes exactly what letspi computed before; none is used to plan.

* ``predict_idm_concatenating``: the IDM neighbour prediction that concatenated [neighbours, ego] and
  called ``take_along_axis`` and a fresh ``idm_acceleration`` every step;
* ``idm_acceleration_per_call``: the IDM acceleration with its constants recomputed every call;
* ``check_inputs_mirrored``: the candidate check whose rear TTC was the front TTC of a copy of the scene
  mirrored in x, with every distance computed;
* ``sf_opt_on_repeated_batch``: ``sf-opt``'s search on the whole batch and prediction repeated per
  candidate, checked by ``check_inputs_mirrored``;
* ``sf_opt_all_candidates``: ``sf-opt``'s search before it was staged: all C candidates of every
  scenario rolled out and checked at once, then ``choose_candidates`` (its ``n_safe_candidates`` info
  counts the safe ones; the staged search reports ``n_candidates_tried`` instead);
* ``sf_check_checking_every_preset``: ``sf-check``'s plans when every preset was checked on every
  scenario (the rule needs them only where the gate consults and the defaults fail a check).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from letspi.constants import DT_S, N_FUTURE
from letspi.method.phases import decision_reason
from letspi.metrics.collision import boxes_overlap
from letspi.metrics.distance import distances
from letspi.metrics.inputs import MetricInputs
from letspi.metrics.kinematics import off_road
from letspi.metrics.ttc import ttc_1d
from letspi.physics.goals import NEUTRAL_LON_FACTOR
from letspi.physics.idm import GAP_FLOOR_FRACTION, IDM_MIN_ACCEL_MPS2, MIN_DESIRED_SPEED_MPS, IdmParams
from letspi.physics.neighbours import idm_prediction_of, idm_start
from letspi.physics.params import SocialForceParams
from letspi.physics.social_force import SocialForceScene, rollout_social_force, rollout_social_force_scene
from letspi.physics.types import NeighbourPrediction, RolloutResult
from letspi.planners.base import PlanBatch, PlanningContext, Proposals
from letspi.planners.decision import decision_info
from letspi.planners.llm import PRESETS_PASS_ALL, PRESETS_PROGRESS
from letspi.planners.sf_check import DecisionPlanner
from letspi.planners.sf_opt import SearchSpace, SocialForceSearchPlanner, candidates
from letspi.safety.plan_check import SafetyCheck, check_plans, min_path_gap_m, predicted_inputs
from letspi.scenario.types import ScenarioBatch


def idm_acceleration_per_call(speed_mps: np.ndarray, desired_speed_mps: np.ndarray, gap_m: np.ndarray,
                              leader_speed_mps: np.ndarray, params: IdmParams) -> np.ndarray:
    """``letspi.physics.idm.idm_acceleration`` as it was (every constant computed in the call)."""
    v = np.maximum(np.asarray(speed_mps, dtype=np.float64), 0.0)
    v0 = np.maximum(np.asarray(desired_speed_mps, dtype=np.float64), MIN_DESIRED_SPEED_MPS)
    has_leader = np.isfinite(gap_m)
    lead = np.where(has_leader, np.asarray(leader_speed_mps, dtype=np.float64), v)
    a_max = np.asarray(params.max_accel_mps2, dtype=np.float64)
    s0 = np.asarray(params.min_gap_m, dtype=np.float64)
    root = 2.0 * np.sqrt(a_max * np.asarray(params.comfort_decel_mps2, dtype=np.float64))
    wanted = s0 + np.maximum(0.0, v * params.time_headway_s + v * (v - lead) / root)
    ratio = np.where(has_leader, (wanted / np.maximum(np.where(has_leader, gap_m, 1.0), GAP_FLOOR_FRACTION * s0)) ** 2,
                     0.0)
    return np.clip(a_max * (1.0 - (v / v0) ** params.delta - ratio), IDM_MIN_ACCEL_MPS2, a_max)


def predict_idm_concatenating(batch: ScenarioBatch) -> NeighbourPrediction:
    """``letspi.physics.neighbours.predict_idm`` as it was: [neighbours, ego] concatenated every step."""
    st = idm_start(batch)
    x, v = st.x, st.v
    xs, vs = [], []
    for k in range(N_FUTURE):
        cand_x = np.concatenate([x, (st.ego_x_m + st.ego_v_mps * (k * DT_S))[:, None]], axis=1)
        cand_v = np.concatenate([v, st.ego_v_mps[:, None]], axis=1)
        gap = np.where(st.has_leader, np.take_along_axis(cand_x, st.lead_idx, axis=1) - x - st.half_len_m, np.inf)
        acc = idm_acceleration_per_call(v, st.desired_speed_mps, gap, np.take_along_axis(cand_v, st.lead_idx, axis=1),
                                        st.params)
        v = np.maximum(v + acc * DT_S, 0.0)
        x = x + v * DT_S
        xs.append(x)
        vs.append(v)
    return idm_prediction_of(st, np.stack(xs, axis=2), np.stack(vs, axis=2))


def check_inputs_mirrored(batch: ScenarioBatch, inp: MetricInputs) -> SafetyCheck:
    """``letspi.safety.plan_check.check_inputs`` as it was: the rear TTC from the scene mirrored in x."""
    flip = np.array([-1.0, 1.0])
    mirrored = replace(inp, ego_xy_m=inp.ego_xy_m * flip, ego_vxy_mps=inp.ego_vxy_mps * flip,
                       nbr_xy_m=inp.nbr_xy_m * flip, nbr_vxy_mps=inp.nbr_vxy_mps * flip)
    ttc, rear, dist = ttc_1d(inp), ttc_1d(mirrored), distances(inp)
    return SafetyCheck(
        min_ttc_s=ttc.min_ttc_s, min_ttc_step=ttc.min_ttc_step, min_ttc_nbr=ttc.min_ttc_nbr,
        min_rear_ttc_s=rear.min_ttc_s, min_rear_ttc_step=rear.min_ttc_step, min_rear_ttc_nbr=rear.min_ttc_nbr,
        min_box_gap_m=dist.min_box_gap_m, min_gap_step=dist.min_gap_step, min_gap_nbr=dist.min_gap_nbr,
        min_path_gap_m=min_path_gap_m(inp), collision=np.asarray(boxes_overlap(inp).any(axis=(1, 2)), dtype=bool),
        off_road=off_road(inp.ego_xy_m[..., 1], inp.ego_width_m, batch.marking_y_m, batch.marking_is_edge),
    )


def repeated(pred: NeighbourPrediction, rows: np.ndarray) -> NeighbourPrediction:
    """The prediction of scenario ``rows[i]`` in row i."""
    return NeighbourPrediction(*(np.asarray(a)[rows] for a in pred))


def sf_opt_on_repeated_batch(planner: SocialForceSearchPlanner, batch: ScenarioBatch, context: PlanningContext,
                             proposals: Proposals) -> PlanBatch:
    """``SocialForceSearchPlanner.simulate`` as it was: the batch and the prediction repeated per candidate."""
    rep, params, cand_goals = candidates(planner.space, batch, context.goals_xy_m, proposals)
    big, big_pred = batch.take(rep), repeated(context.neighbours, rep)
    roll = rollout_social_force(big, params, cand_goals, big_pred)
    check = check_inputs_mirrored(big, predicted_inputs(big, roll.xy_m, roll.vxy_mps, big_pred))
    return choose_candidates(planner.space, len(batch), roll, cand_goals, check)


def sf_opt_all_candidates(planner: SocialForceSearchPlanner, batch: ScenarioBatch, context: PlanningContext,
                          proposals: Proposals) -> PlanBatch:
    """``SocialForceSearchPlanner.simulate`` before the staged search: every candidate of every scenario
    rolled out and checked in one call, then ``choose_candidates``."""
    pred = context.neighbours
    rep, params, cand_goals = candidates(planner.space, batch, context.goals_xy_m, proposals)
    roll = rollout_social_force_scene(SocialForceScene.from_batch(batch, pred).take(rep), params, cand_goals)
    check = check_plans(batch, roll.xy_m, roll.vxy_mps, pred, rows=rep)
    return choose_candidates(planner.space, len(batch), roll, cand_goals, check)


def choose_candidates(space: SearchSpace, b: int, roll: RolloutResult, cand_goals: np.ndarray,
                      check: SafetyCheck) -> PlanBatch:
    """The plan of each of ``b`` scenarios from its C candidates (rows scenario-major, ``space.grid()``
    order): the cheapest safe one, else the best ranked (``letspi.planners.sf_opt``'s docstring)."""
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


def sf_check_checking_every_preset(planner: DecisionPlanner, batch: ScenarioBatch,
                                   context: PlanningContext) -> PlanBatch:
    """``sf-check``'s plan as it was: every preset checked on every scenario, the rule where the gate consults,
    the shield's preset alternatives from those checks."""
    decider = planner.decider
    checks = decider.check(batch, context.goals_xy_m, context.neighbours)
    risk = decider.risk_scores(batch, checks)
    consulted = decider.consulted(risk)
    chosen = np.where(consulted, decider.rule(checks), 0)
    values = decider.presets.values[chosen]
    names = [decider.presets.names[k] for k in chosen]
    reasons = [decision_reason(decider, checks.row(i), names[i], bool(consulted[i]), float(risk[i]))
               for i in range(len(batch))]
    params = SocialForceParams.from_matrix(
        np.concatenate([values[:, :6], np.full((len(batch), 1), planner.params.r_col_m)], axis=1))
    info = decision_info(names, consulted, risk, np.zeros(len(batch)), reasons)
    extra = {PRESETS_PASS_ALL: checks.passes_all(), PRESETS_PROGRESS: checks.progress_m}
    proposals = Proposals(params=params, lon_factor=values[:, 6], lane_factor=values[:, 7], info=info, extra=extra)
    return planner.simulate(batch, context, proposals)
