"""closed-loop-hybrid in real SUMO: replayed leaders keep their events, followers react, scripted
actors keep their log, and the replanning step is a separate, swappable object."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_simulation_support import BrakePlanner, RecordingPlanner, SwervePlanner, as_built

from letspi.constants import DT_S, N_FUTURE, N_TOTAL, T0_INDEX
from letspi.highd.events import read_events
from letspi.highd.io import read_recordings
from letspi.scenario.build import LANE_WIDTH_M, VehicleSpec, straight_road_scenario
from letspi.scenario.extract import extract_scenarios
from letspi.scenario.scripted import recording_events, scripted_neighbours
from letspi.scenario.types import ScenarioBatch, concat_batches
from letspi.simulation import ClosedLoopChunk, ClosedLoopConfig, PlannerSpec, chunk_metrics, run_closed_loop
from letspi.simulation.config import HandoverConfig
from letspi.simulation.engine import simulate_group
from letspi.simulation.replan import PeriodicReplanner, Replan, SimulatedStates
from letspi.simulation.session import SumoSession
from letspi.trafficgen.generate import generate_highd

pytestmark = pytest.mark.sumo
LOG, REACTIVE, HYBRID = "closed-loop-log", "closed-loop-reactive", "closed-loop-hybrid"
FUT = slice(T0_INDEX + 1, N_TOTAL)


def _run(planner: object, batch: ScenarioBatch, mode: str, **kw: object) -> ClosedLoopChunk:
    scripted = kw.pop("scripted_nbr", None)
    config = replace(kw.pop("config", None) or ClosedLoopConfig(simulator="sumo"), mode=mode, **kw)  # type: ignore[arg-type]
    chunk = ClosedLoopChunk.concat(list(run_closed_loop(as_built(planner), batch, config,  # type: ignore[arg-type]
                                                        scripted_nbr=scripted)))  # type: ignore[arg-type]
    return chunk.take(np.argsort(chunk.indices))


def _braking_leader(batch: ScenarioBatch, slot: int, start_s: float, decel_mps2: float,
                    duration_s: float) -> ScenarioBatch:
    """``batch`` with neighbour ``slot`` braking at ``decel_mps2`` from ``start_s`` for ``duration_s``
    (constant speed before and after; its position at t = 0 unchanged)."""
    xy, vxy = batch.nbr_xy_m.copy(), batch.nbr_vxy_mps.copy()
    t = (np.arange(N_TOTAL) - T0_INDEX) * DT_S
    v0 = float(vxy[0, slot, T0_INDEX, 0])
    v = v0 - decel_mps2 * np.clip(t - start_s, 0.0, duration_s)
    x = xy[0, slot, T0_INDEX, 0] + np.concatenate([[0.0], np.cumsum((v[1:] + v[:-1]) / 2 * DT_S)])
    x -= x[T0_INDEX] - xy[0, slot, T0_INDEX, 0]
    xy[0, slot, :, 0], vxy[0, slot, :, 0] = x, v
    return replace(batch, nbr_xy_m=xy.astype(np.float32), nbr_vxy_mps=vxy.astype(np.float32))


def test_a_leaders_recorded_hard_brake_still_happens_and_the_follower_reacts() -> None:
    leader = VehicleSpec(x0_m=45.0, speed_mps=30.0)
    follower = VehicleSpec(x0_m=-30.0, speed_mps=30.0)
    batch = _braking_leader(straight_road_scenario(neighbours=[leader, follower]), 0, 1.0, 7.0, 2.0)
    hybrid = _run(BrakePlanner(2.0), batch, HYBRID)
    reactive = _run(BrakePlanner(2.0), batch, REACTIVE)
    log_v = batch.nbr_vxy_mps[0, 0, FUT, 0]
    assert log_v.min() == pytest.approx(16.0, abs=1e-3)
    # hybrid: the leader ahead replays its log, hard brake included; the follower is SUMO's from t = 0
    np.testing.assert_allclose(hybrid.nbr_vxy_mps[0, 0, :, 0], log_v, atol=1e-4)
    np.testing.assert_allclose(hybrid.nbr_xy_m[0, 0], batch.nbr_xy_m[0, 0, FUT], atol=1e-3)
    assert hybrid.nbr_handover_step[0, :2].tolist() == [-1, 0]
    # reactive (every neighbour SUMO's from t = 0): the leader never brakes
    assert reactive.nbr_vxy_mps[0, 0, :, 0].min() > 25.0
    # the handed-over follower slowed with the braking ego, never above its recorded speed
    v_follow = hybrid.nbr_vxy_mps[0, 1, :, 0]
    assert v_follow[-1] < 28.0 and np.all(v_follow <= batch.nbr_vxy_mps[0, 1, FUT, 0] + 1e-3)
    assert not chunk_metrics(batch, hybrid).collision.any()


def _speed_profile(v0_mps: float, segments: list[tuple[float, float, float]]) -> np.ndarray:
    """(N_TOTAL,) speeds: ``v0_mps`` at t = 0 plus constant accelerations (start_s, duration_s, accel_mps2)."""
    t = (np.arange(N_TOTAL) - T0_INDEX) * DT_S
    a = sum((np.where((t >= t0) & (t < t0 + d), acc, 0.0) for t0, d, acc in segments), np.zeros(N_TOTAL))
    v = np.concatenate([[0.0], np.cumsum(a[:-1]) * DT_S])
    return np.maximum(v - v[T0_INDEX] + v0_mps, 0.0)


def _lane_change(start_s: float, end_s: float) -> np.ndarray:
    """(N_TOTAL,) lateral offsets of a smooth change by one lane to the left between the two times."""
    u = np.clip(((np.arange(N_TOTAL) - T0_INDEX) * DT_S - start_s) / (end_s - start_s), 0.0, 1.0)
    return LANE_WIDTH_M * u * u * (3.0 - 2.0 * u)


def _path(x0_m: float, v_mps: np.ndarray) -> np.ndarray:
    """(N_TOTAL,) positions along the speeds ``v_mps`` (trapezoidal), ``x0_m`` at t = 0."""
    x = np.concatenate([[0.0], np.cumsum((v_mps[1:] + v_mps[:-1]) / 2 * DT_S)])
    return x - x[T0_INDEX] + x0_m


def _drive(batch: ScenarioBatch, slot: int | None, v_mps: np.ndarray, y_m: np.ndarray | None = None) -> ScenarioBatch:
    """``batch`` (one scenario) with the ego (``slot`` None) or neighbour ``slot`` driving at ``v_mps``
    along x (same x at t = 0) and, if given, at lateral offsets ``y_m``."""
    if slot is None:
        x, y = _path(0.0, v_mps), np.zeros(N_TOTAL) if y_m is None else y_m
        vy = np.gradient(y, DT_S)
        axy = np.stack([np.gradient(v_mps, DT_S), np.gradient(vy, DT_S)], -1)
        return replace(batch, ego_xy_m=np.stack([x, y], -1)[None].astype(np.float32),
                       ego_vxy_mps=np.stack([v_mps, vy], -1)[None].astype(np.float32),
                       ego_axy_mps2=axy[None].astype(np.float32))
    xy, vxy = batch.nbr_xy_m.copy(), batch.nbr_vxy_mps.copy()
    xy[0, slot, :, 0], vxy[0, slot, :, 0] = _path(float(xy[0, slot, T0_INDEX, 0]), v_mps), v_mps
    if y_m is not None:
        xy[0, slot, :, 1], vxy[0, slot, :, 1] = y_m, np.gradient(y_m, DT_S)
    return replace(batch, nbr_xy_m=xy.astype(np.float32), nbr_vxy_mps=vxy.astype(np.float32))


def _scripted_stress_batch() -> tuple[ScenarioBatch, np.ndarray]:
    """Three recorded human drives through scripted events, and the mask of the events' actors:
    0: the leader (20.5 m ahead) brakes at 7 m/s^2 for 2 s from t = 1 s, the human 0.8 s later, the
       follower (1 s behind) 0.8 s after the human;
    1: a slower car 10 m ahead in the left lane cuts in over 2 s from t = 0.5 s, the human brakes at
       3 m/s^2 for 2 s from t = 1 s, its follower (1.2 s behind) 0.8 s later;
    2: the human changes into the left lane 20 m ahead of a faster car there, which brakes at 2 m/s^2."""
    v = 30.0
    brake = straight_road_scenario(
        neighbours=[VehicleSpec(x0_m=25.0, speed_mps=v), VehicleSpec(x0_m=-34.5, speed_mps=v)], scenario_id="brake")
    brake = _drive(brake, 0, _speed_profile(v, [(1.0, 2.0, -7.0)]))
    brake = _drive(brake, None, _speed_profile(v, [(1.8, 2.0, -7.0)]))
    brake = _drive(brake, 1, _speed_profile(v, [(2.6, 2.0, -7.0)]))
    cut_in = straight_road_scenario(neighbours=[VehicleSpec(x0_m=14.5, speed_mps=26.0, lane_offset=1),
                                                VehicleSpec(x0_m=-40.5, speed_mps=v)], scenario_id="cut-in")
    cut_in = _drive(cut_in, 0, np.full(N_TOTAL, 26.0), LANE_WIDTH_M - _lane_change(0.5, 2.5))
    cut_in = _drive(cut_in, None, _speed_profile(v, [(1.0, 2.0, -3.0)]))
    cut_in = _drive(cut_in, 1, _speed_profile(v, [(1.8, 2.0, -3.0)]))
    merge = straight_road_scenario(
        ego_speed_mps=27.0, neighbours=[VehicleSpec(x0_m=-24.5, speed_mps=32.0, lane_offset=1)], scenario_id="merge")
    merge = _drive(merge, None, _speed_profile(27.0, [(0.5, 3.0, 1.0)]), _lane_change(0.5, 3.0))
    merge = _drive(merge, 0, _speed_profile(32.0, [(1.5, 2.0, -2.0)]))
    batch = concat_batches([brake, cut_in, merge])
    scripted = np.zeros(batch.nbr_id.shape, dtype=bool)
    scripted[0, 0] = scripted[1, 0] = True  # the braking leader, the car cutting in
    return batch, scripted


def test_the_human_on_a_scripted_stress_batch_is_not_at_fault_and_its_critical_encounters_stay() -> None:
    """The human's recorded drives replayed among neighbours of the hybrid mode: no contact (at fault
    or not), the same critical encounters as log replay (min TTC < 3 s), where closed-loop-reactive
    loses them; the followers are SUMO's (from t = 0, or once the ego's box enters their lane)."""
    batch, scripted = _scripted_stress_batch()
    human = PlannerSpec.of("human")
    log = chunk_metrics(batch, _run(human, batch, LOG))
    critical = log.min_ttc_s < 3.0
    assert critical.tolist() == [True, True, False] and not log.collision.any()
    hybrid_ch = _run(human, batch, HYBRID, scripted_nbr=scripted)
    hybrid = chunk_metrics(batch, hybrid_ch)
    assert not hybrid.collision.any() and not hybrid.collision_at_fault.any()
    np.testing.assert_allclose(hybrid.min_ttc_s[critical], log.min_ttc_s[critical], rtol=1e-3)  # events as recorded
    np.testing.assert_allclose(hybrid_ch.nbr_xy_m[scripted], batch.nbr_xy_m[:, :, FUT][scripted], atol=1e-3)
    assert hybrid_ch.nbr_handover_step[:2, 1].tolist() == [0, 0]
    assert hybrid_ch.nbr_handover_step[2, 0] > 0  # the car in the left lane: once the ego's box enters it
    reactive = chunk_metrics(batch, _run(human, batch, REACTIVE))
    assert (reactive.min_ttc_s[critical] >= 3.0).all()


@pytest.mark.parametrize("headway_s", [0.6, 1.0, 1.5])
def test_a_follower_does_not_rear_end_an_ego_braking_within_the_allowed_deceleration(headway_s: float) -> None:
    """Braking at the comfort bound (3 m/s^2, always allowed) and, behind a leader braking at 8 m/s^2,
    at 8 m/s^2 (allowed by the leader's braking): the replayed follower of closed-loop-log hits the ego."""
    gap = 30.0 * headway_s
    follower = VehicleSpec(x0_m=-(gap + 4.5), speed_mps=30.0)
    leader = VehicleSpec(x0_m=40.0, speed_mps=30.0)
    comfort = straight_road_scenario(neighbours=[follower], scenario_id="comfort")
    hard = _braking_leader(straight_road_scenario(neighbours=[follower, leader], scenario_id="hard"), 1, 0.0, 8.0, 3.0)
    for planner, batch in ((BrakePlanner(3.0), comfort), (BrakePlanner(8.0), hard)):
        hybrid = _run(planner, batch, HYBRID)
        m = chunk_metrics(batch, hybrid)
        assert not m.collision.any() and not hybrid.sumo_collision.any(), (planner, headway_s)
        assert np.nanmin(m.min_box_gap_m) > 0.0
        assert hybrid.nbr_handover_step[0, 0] == 0
    log = _run(BrakePlanner(8.0), hard, LOG)
    assert log.sumo_collision.all()  # the same follower on its log runs into the ego


def test_a_scripted_actor_behind_the_ego_keeps_its_log() -> None:
    follower = VehicleSpec(x0_m=-(20.0 + 4.5), speed_mps=30.0)
    batch = straight_road_scenario(neighbours=[follower])
    scripted = np.zeros((1, batch.n_neighbours), dtype=bool)
    scripted[0, 0] = True
    kept = _run(BrakePlanner(6.0), batch, HYBRID, scripted_nbr=scripted)
    np.testing.assert_allclose(kept.nbr_xy_m[0, 0], batch.nbr_xy_m[0, 0, FUT], atol=1e-3)
    assert kept.nbr_handover_step[0, 0] == -1 and kept.sumo_collision.all()  # it drives on into the ego
    reacting = _run(BrakePlanner(6.0), batch, HYBRID)
    assert reacting.nbr_handover_step[0, 0] == 0 and not reacting.sumo_collision.any()


def test_hand_over_when_the_ego_passes_or_changes_lanes_keeps_position_and_speed_continuous() -> None:
    slow_left = VehicleSpec(x0_m=20.0, speed_mps=20.0, lane_offset=1)  # the ego overtakes it
    wide = ClosedLoopConfig(handover=HandoverConfig(lanes=1))
    batch = straight_road_scenario(ego_speed_mps=30.0, neighbours=[slow_left])
    passed = _run(RecordingPlanner(), batch, HYBRID, config=wide)
    # its front bumper passes the ego's rear bumper after (20 + 4.5) / 10 = 2.45 s = step 60.25;
    # the rule is checked on the previous frame, so SUMO drives it from step 62
    step = int(passed.nbr_handover_step[0, 0])
    assert step == 62
    xy, v = passed.nbr_xy_m[0, 0], passed.nbr_vxy_mps[0, 0, :, 0]
    log_xy = batch.nbr_xy_m[0, 0, FUT]
    np.testing.assert_allclose(xy[: step + 1], log_xy[: step + 1], atol=2e-3)  # position continuous
    assert np.abs(np.diff(v[step - 2 : step + 3])).max() < 0.2  # speed continuous (<= 5 m/s^2 over a frame)
    # with the default rule (lanes the ego's box covers) a vehicle in the next lane keeps its log
    assert _run(RecordingPlanner(), batch, HYBRID).nbr_handover_step[0, 0] == -1

    # an ego changing lanes reaches the follower in the target lane when its box enters that lane
    swerve = SwervePlanner(1.5)
    sid = "swerve-left"
    side = 1 if sum(map(ord, sid)) % 2 else -1
    follower = VehicleSpec(x0_m=-40.0, speed_mps=30.0, lane_offset=side)
    lane_change = straight_road_scenario(neighbours=[follower], scenario_id=sid)
    ch = _run(swerve, lane_change, HYBRID)
    # the box edge crosses the marking (y = LANE_WIDTH_M / 2 - 0.9 = 0.975 m) after 0.9 s = step 21.5
    assert 22 <= ch.nbr_handover_step[0, 0] <= 24


class _EveryOtherScenario:
    """A replanner that plans every scenario at t = 0 and afterwards only scenario 1, at t = 1 s, with
    a brake plan: the engine follows a plan only for the scenarios it was made for."""

    def __init__(self, batch: ScenarioBatch) -> None:
        self.first = PeriodicReplanner(RecordingPlanner(), batch, N_FUTURE, "none")

    @property
    def frames(self) -> list[int]:
        return [T0_INDEX, T0_INDEX + 25]

    def plans(self, frame: int, states: SimulatedStates) -> Replan | None:
        if frame == T0_INDEX:
            return self.first.plans(frame, states)
        if frame != T0_INDEX + 25:
            return None
        # re-plan scenario 1 from its simulated state at this frame: a brake plan from there
        centre = states.ego_xy_m[1, frame]
        v0 = states.ego_vxy_mps[1, frame]
        speed = np.maximum(v0[0] - 4.0 * np.arange(1, N_FUTURE + 1) * DT_S, 0.0)
        xy = np.stack([centre[0] + np.cumsum(speed) * DT_S, np.full(N_FUTURE, centre[1])], -1)
        vxy = np.stack([speed, np.zeros(N_FUTURE)], -1)
        return Replan(rows=np.array([1]), xy_m=xy[None], vxy_mps=vxy[None], goals_xy_m=xy[None, -1],
                      follow_until=np.array([N_TOTAL - 1]), info={"braked": np.array([1.0])}, plan_s=0.0)


def test_the_replanning_step_is_a_separate_object_that_plans_for_the_scenarios_due() -> None:
    batch = concat_batches([straight_road_scenario(scenario_id=f"s{i}") for i in range(2)])
    with SumoSession(ClosedLoopConfig()) as session:
        ch = simulate_group(session, RecordingPlanner(), batch, ClosedLoopConfig(), future="none",
                            replanner=_EveryOtherScenario(batch))
    assert ch.replan_step.tolist() == [0, 25]
    v = ch.ego_vxy_mps[:, :, 0]
    np.testing.assert_allclose(v[0], 30.0, atol=1e-6)  # scenario 0 follows its t = 0 plan to the end
    np.testing.assert_allclose(v[1, :25], 30.0, atol=1e-6)
    assert v[1, -1] == pytest.approx(30.0 - 4.0 * 100 * DT_S, abs=1e-6)  # scenario 1 braked from t = 1 s
    assert np.isnan(ch.plan_xy_m[0, 1]).all() and np.isfinite(ch.plan_xy_m[1, 1]).all()
    assert np.isnan(ch.plan_info["braked"][0, 1]) and ch.plan_info["braked"][1, 1] == 1.0


@pytest.mark.slow  # generates a few minutes of stress traffic
def test_human_on_stress_traffic_is_never_at_fault_and_critical_encounters_are_kept(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    """The log replay of the human has no collision; in the hybrid mode the human stays at 0 % CR at
    fault and at least 90 % of its critical windows (min TTC < 3 s) stay critical; recorded hard
    brakes of replayed actors happen as recorded for a planner that drives differently (idm)."""
    d = tmp_path_factory.mktemp("stress")
    generate_highd(d, minutes=2.0, seed=11, criticality="stress")
    recs = read_recordings(d)
    batch = extract_scenarios(recs, max_scenarios=96, seed=0, critical_share=1.0,
                              events={r.recording_id: read_events(d, r.recording_id) for r in recs})
    events = recording_events(d)
    scripted = scripted_neighbours(batch, events)
    assert scripted.any()
    log = chunk_metrics(batch, _run(PlannerSpec.of("human"), batch, LOG))
    assert not log.collision.any()
    critical = log.min_ttc_s < 3.0
    assert critical.sum() >= 10
    hybrid_ch = _run(PlannerSpec.of("human"), batch, HYBRID, scripted_nbr=scripted)
    hybrid = chunk_metrics(batch, hybrid_ch)
    assert not hybrid.collision_at_fault.any()
    assert (hybrid.min_ttc_s[critical] < 3.0).mean() >= 0.9
    assert (hybrid_ch.nbr_handover_step >= 0).any()  # some neighbours were SUMO's
    # hard-brake actors that are neighbours replay their log under another planner
    idm = _run(PlannerSpec.of("idm"), batch, HYBRID, scripted_nbr=scripted)
    ev = read_events(d, 1)
    assert ev is not None
    brakes = set(ev.loc[ev["kind"] == "hard_brake", "id"].astype(int))
    actor = scripted & np.isin(batch.nbr_id, list(brakes))
    assert actor.any()
    ok = idm.nbr_valid[actor]
    np.testing.assert_allclose(idm.nbr_xy_m[actor][ok], batch.nbr_xy_m[:, :, FUT][actor][ok], atol=1e-3)
