"""Reflection: safety reports on hand-built scenarios and the propose -> check -> refine loop."""

from __future__ import annotations

import numpy as np
import pytest

from letspi.constants import DT_S
from letspi.method.reflection import (
    NEUTRAL_LON_FACTOR,
    Proposal,
    ReflectionContext,
    reflect,
    safety_report,
    simulate_proposal,
)
from letspi.method.thresholds import ReflectionThresholds
from letspi.physics.goals import KinematicGoalPredictor
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.params import SocialForceParams
from letspi.physics.types import NeighbourPrediction
from letspi.safety.plan_check import check_plans
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import ScenarioBatch

F = 125


def _unsafe_scenario() -> ScenarioBatch:
    """Ego at 33 m/s closing on a 20 m/s leader 40 m ahead; a car in the left lane far behind."""
    return straight_road_scenario(
        ego_speed_mps=33.0,
        neighbours=[VehicleSpec(x0_m=40.0, speed_mps=20.0), VehicleSpec(x0_m=-60.0, speed_mps=30.0, lane_offset=1)],
        scenario_id="unsafe_leader",
    )


def _scripted(ctx: ReflectionContext) -> Proposal:
    """Weak k_np and an extended goal first; then k_np x 2.5 and the goal shortened, as the report suggests."""
    if ctx.report is None:
        return Proposal(SocialForceParams(k_np=3.0), lon_factor=0.0, rationale="keep speed",
                        prompt="initial prompt", reply='{"k_np": 3}')
    assert ctx.previous is not None
    assert any(v.category == "front" for v in ctx.report.violations)
    p = ctx.previous.params
    stronger = SocialForceParams(**{**p.as_dict(), "k_np": p.k_np * 2.5})
    return Proposal(stronger, lon_factor=min(1.0, ctx.previous.lon_factor + 0.5), rationale="front conflict",
                    prompt=ctx.report.to_text(ctx.previous), reply=f'{{"k_np": {stronger.k_np}}}')


def test_reflection_fires_and_refinement_passes_thresholds() -> None:
    th = ReflectionThresholds(max_decel_mps2=None)  # safety semantics only; braking: its own test
    res = reflect(_unsafe_scenario(), _scripted, th)
    assert not res.initial.safe
    assert res.initial.metrics["collision"] == 1.0 or res.initial.metrics["min_ttc_s"] < th.ttc_s
    assert res.validated and res.final.safe
    assert res.final_index == len(res.iterations) - 1 >= 1
    after = res.metrics_after
    assert after["min_ttc_s"] >= th.ttc_s and after["min_rear_ttc_s"] >= th.ttc_s
    assert after["min_path_gap_m"] >= th.min_dist_m
    assert after["collision"] == 0.0 and after["off_road"] == 0.0
    # every iteration recorded with the proposer's texts; later prompts carry the report
    assert [r.iteration for r in res.iterations] == list(range(len(res.iterations)))
    assert res.iterations[0].proposal.prompt == "initial prompt"
    assert "Safety analysis" in (res.iterations[1].proposal.prompt or "")
    d = res.final.to_dict()
    assert d["safe"] and d["proposal"]["params"]["k_np"] == res.final.proposal.params.k_np
    # the recorded metrics are those of an independent re-simulation
    sc = _unsafe_scenario()
    pred = predict_neighbours(sc, NeighbourPredictionMode.IDM)
    plan = simulate_proposal(sc, SocialForceParams.stack([res.final.proposal.params]),
                             np.array([res.final.proposal.lon_factor]), np.array([res.final.proposal.lane_factor]),
                             KinematicGoalPredictor().predict_goals(sc).top, pred)
    chk = check_plans(sc, plan.xy_m, plan.vxy_mps, pred)
    assert bool(chk.safe(th.ttc_s, th.min_dist_m)[0])
    np.testing.assert_allclose(chk.min_ttc_s[0], after["min_ttc_s"])


def test_max_iterations_bounds_calls_and_zero_disables_refinement() -> None:
    calls: list[int] = []

    def stubborn(ctx: ReflectionContext) -> Proposal:
        calls.append(ctx.iteration)
        return Proposal(SocialForceParams(k_np=1.0), lon_factor=0.0)

    res = reflect(_unsafe_scenario(), stubborn, ReflectionThresholds(max_iterations=2), unsafe_choice="last")
    assert calls == [0, 1, 2] and not res.validated and res.final_index == 2
    calls.clear()
    res0 = reflect(_unsafe_scenario(), stubborn, ReflectionThresholds(max_iterations=0))
    assert calls == [0] and len(res0.iterations) == 1 and not res0.validated


def test_proposals_are_clamped_and_goal_factors_frozen_without_ga() -> None:
    def wild(ctx: ReflectionContext) -> Proposal:
        if ctx.iteration == 0:
            return Proposal(SocialForceParams(k_np=500.0, tau_s=float("nan")), lon_factor=7.0, lane_factor=np.nan)
        return Proposal(SocialForceParams(k_np=30.0), lon_factor=1.0, lane_factor=0.5)

    res = reflect(_unsafe_scenario(), wild, ReflectionThresholds(max_iterations=1), goal_adjustment=False)
    p0 = res.iterations[0].proposal
    assert p0.params.k_np == 60.0 and p0.params.tau_s == 1.0 and p0.lon_factor == 1.0 and p0.lane_factor == 0.0
    assert set(p0.clamped_fields) == {"k_np", "tau_s", "lon_factor", "lane_factor"}
    if len(res.iterations) > 1:
        p1 = res.iterations[1].proposal
        assert (p1.lon_factor, p1.lane_factor) == (1.0, 0.0)
        assert p1.meta["goal_factors_frozen"] == [1.0, 0.5]


def _constant_velocity(sc: ScenarioBatch) -> NeighbourPrediction:
    return predict_neighbours(sc, NeighbourPredictionMode.CONSTANT_VELOCITY)


def _const_plan(speed_mps: float, y_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    t = (np.arange(F) + 1) * DT_S
    xy = np.stack([speed_mps * t, np.full(F, y_m)], axis=-1)[None]
    vxy = np.broadcast_to(np.array([speed_mps, 0.0]), (1, F, 2)).copy()
    return xy, vxy


def test_report_names_front_neighbour_and_step() -> None:
    # slot 0: left-lane car (harmless); slot 1: slow leader in the ego lane -> the front conflict
    sc = straight_road_scenario(
        ego_speed_mps=30.0,
        neighbours=[VehicleSpec(x0_m=10.0, speed_mps=30.0, lane_offset=1), VehicleSpec(x0_m=60.0, speed_mps=20.0)],
    )
    xy, vxy = _const_plan(30.0)
    pred = _constant_velocity(sc)
    th = ReflectionThresholds()
    rep = safety_report(sc, xy, vxy, pred, th)[0]
    assert rep.violated
    front = next(v for v in rep.violations if v.metric == "front_ttc")
    # hand computation: gap(t) = 60 - 4.5 - 10 t, TTC = gap / 10 decreasing until contact at t = 5.55 s > 5 s
    t = (np.arange(F) + 1) * DT_S
    ttc = (60.0 - 4.5 - 10.0 * t) / 10.0
    assert front.step == int(np.argmin(ttc)) == F - 1
    np.testing.assert_allclose(front.value, ttc.min(), atol=1e-4)
    assert front.time_s == pytest.approx((front.step + 1) * DT_S)
    assert (front.nbr_slot, front.vehicle_id) == (1, int(sc.nbr_id[0, 1]))
    assert front.relative == "front" and front.category == "front"
    assert front.ego_lane_id == front.nbr_lane_id == 7
    text = rep.to_text()
    assert f"vehicle #{front.vehicle_id} (slot 1) ahead in the same lane" in text
    assert "increase k_np" in text and "lon_factor" in text
    # the in-path gap falls below 2 m? (at t = 5 s: 5.5 m) -> no
    assert not any(v.metric == "in_path_gap" for v in rep.violations)


def test_report_rear_approach_and_side() -> None:
    # slot 0: fast follower in the ego lane (rear conflict); slot 1: right-lane car alongside
    sc = straight_road_scenario(
        ego_speed_mps=25.0,
        neighbours=[VehicleSpec(x0_m=-30.0, speed_mps=40.0), VehicleSpec(x0_m=0.0, speed_mps=25.0, lane_offset=-1)],
    )
    xy, vxy = _const_plan(25.0)
    rep = safety_report(sc, xy, vxy, _constant_velocity(sc))[0]
    rear = next(v for v in rep.violations if v.metric == "rear_ttc")
    gap = 30.0 - 4.5 - 15.0 * (np.arange(F) + 1) * DT_S
    first_contact = int(np.argmax(gap <= 0))
    # located before the first contact: the last pre-contact step has the smallest TTC
    assert rear.step == first_contact - 1
    assert (rear.nbr_slot, rear.relative, rear.category) == (0, "rear", "rear")
    contact = next(v for v in rep.violations if v.metric == "contact")
    assert contact.step == first_contact and contact.relative == "rear" and contact.nbr_slot == 0
    assert "Rear conflict" in rep.to_text() and "do not shorten" in rep.to_text()

    # side: the ego drifts right into the car alongside -> contact from the left of that car = right of ego
    y = np.linspace(0.0, -3.75, F)
    xy2 = xy.copy()
    xy2[0, :, 1] = y
    sc2 = straight_road_scenario(
        ego_speed_mps=25.0,
        neighbours=[VehicleSpec(x0_m=-90.0, speed_mps=25.0), VehicleSpec(x0_m=0.0, speed_mps=25.0, lane_offset=-1)],
    )
    rep2 = safety_report(sc2, xy2, vxy, _constant_velocity(sc2))[0]
    side = next(v for v in rep2.violations if v.metric == "contact")
    assert side.nbr_slot == 1 and side.relative == "right" and side.category == "side"
    assert side.nbr_lane_id == 8
    assert "lane_factor towards -1 (left)" in rep2.to_text()


def test_report_is_vectorised_and_consistent_with_check_plans() -> None:
    sc = straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(x0_m=60.0, speed_mps=20.0)])
    batch = sc.take([0, 0, 0])
    pred = _constant_velocity(batch)
    speeds = [30.0, 20.0, 45.0]
    plans = [_const_plan(s) for s in speeds]
    xy = np.concatenate([p[0] for p in plans])
    vxy = np.concatenate([p[1] for p in plans])
    reps = safety_report(batch, xy, vxy, pred, ReflectionThresholds(max_decel_mps2=None))
    chk = check_plans(batch, xy, vxy, pred)
    assert [r.safe for r in reps] == list(chk.safe(1.5, 2.0))
    assert reps[1].safe and "SAFE" in reps[1].to_text()
    assert not reps[2].safe and any(v.metric == "contact" for v in reps[2].violations)


def test_pet_optional() -> None:
    sc = straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(x0_m=20.0, speed_mps=30.0)])
    xy, vxy = _const_plan(30.0)
    pred = _constant_velocity(sc)
    no_pet = safety_report(sc, xy, vxy, pred)[0]
    assert "min_pet_s" not in no_pet.metrics and no_pet.safe
    with_pet = safety_report(sc, xy, vxy, pred, ReflectionThresholds(pet_s=1.0))[0]
    # same speed 30 m/s, bumper gap 15.5 m -> time gap ~0.52 s (grid quantised) < 1 s
    pet = next(v for v in with_pet.violations if v.metric == "pet")
    assert pet.nbr_slot == 0 and pet.relative == "front" and 0.4 < pet.value < 0.6


def test_neutral_lon_factor_keeps_goal() -> None:
    sc = _unsafe_scenario()
    pred = predict_neighbours(sc, NeighbourPredictionMode.IDM)
    goal = np.array([[120.0, 0.0]])
    plan = simulate_proposal(sc, SocialForceParams.stack([SocialForceParams()]), np.array([NEUTRAL_LON_FACTOR]),
                             np.array([0.0]), goal, pred)
    np.testing.assert_allclose(plan.goals_xy_m, goal)
    assert plan.xy_m.shape == (1, F, 2)


def test_harsh_braking_is_a_violation_with_a_tau_suggestion() -> None:
    sc = straight_road_scenario(ego_speed_mps=30.0)
    xy, vxy = _const_plan(30.0)
    vxy = vxy.copy()
    vxy[0, 10:, 0] = 29.6  # a 0.4 m/s drop in one 0.04 s step: 10 m/s^2 > 8 at step 10
    th = ReflectionThresholds()
    rep = safety_report(sc, xy, vxy, _constant_velocity(sc), th)[0]
    v = next(v for v in rep.violations if v.metric == "harsh_braking")
    assert v.step == 10 and abs(v.value - 10.0) < 1e-6 and v.category == "dynamics"
    text = rep.to_text()
    assert "harsh braking" in text and "increase tau" in text
    assert rep.metrics["max_decel_mps2"] == v.value
    assert not safety_report(sc, xy, vxy, _constant_velocity(sc), ReflectionThresholds(max_decel_mps2=None))[0].violated
