"""Closed-loop engine in real SUMO (libsumo, in this process): replay, replanning, reactive traffic,
and SUMO's collision detection against the metric code."""

from __future__ import annotations

from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from test_simulation_support import (
    BrakePlanner,
    RecordingPlanner,
    SwervePlanner,
    WildPlanner,
    as_built,
    generated_batch,
)

from letspi.assembly.planners import build_planners
from letspi.constants import N_TOTAL, T0_INDEX
from letspi.metrics.collision import boxes_overlap
from letspi.metrics.compute import compute_metrics, human_future
from letspi.metrics.inputs import MetricInputs
from letspi.planners.options import PlannerOptions
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.queries import lane_index_of
from letspi.scenario.types import CONTEXT_FIELDS, ScenarioBatch, concat_batches
from letspi.simulation import (
    ClosedLoopChunk,
    ClosedLoopConfig,
    DriverModelConfig,
    PlannerSpec,
    chunk_metrics,
    run_closed_loop,
    scored_batch,
)
from letspi.simulation.drivers import estimate_driver_params
from letspi.simulation.replan import SimulatedStates, replanning_batch

pytestmark = pytest.mark.sumo
LOG, REACTIVE = "closed-loop-log", "closed-loop-reactive"


@pytest.fixture(scope="module")
def traffic(tmp_path_factory: pytest.TempPathFactory) -> ScenarioBatch:
    return generated_batch(tmp_path_factory.mktemp("cl_traffic"), n=48)


def make_planner(kind: str):
    return build_planners([kind], PlannerOptions())[0].planner


def _run(planner: object, batch: ScenarioBatch, mode: str, **kw: object) -> ClosedLoopChunk:
    config = replace(kw.pop("config", None) or ClosedLoopConfig(simulator="sumo"), mode=mode, **kw)  # type: ignore[arg-type]
    chunk = ClosedLoopChunk.concat(list(run_closed_loop(as_built(planner), batch, config)))  # type: ignore[arg-type]
    return chunk.take(np.argsort(chunk.indices))


@pytest.mark.slow  # over ~10 s on a loaded 2-core machine (notes/reliability.md)
def test_human_in_log_mode_reproduces_the_log_and_its_open_loop_metrics(traffic: ScenarioBatch) -> None:
    assert set(np.unique(traffic.driving_direction)) == {1, 2}
    # neighbours are chosen at t = 0 (present then); vehicles entering later are context vehicles
    leaving = traffic.nbr_valid[:, :, T0_INDEX] & ~traffic.nbr_valid[:, :, -1]
    assert leaving.any() and traffic.ctx_valid.any()  # vehicles leave the window mid-run, others enter it
    ch = _run(PlannerSpec.of("human"), traffic, LOG)
    np.testing.assert_array_equal(ch.indices, np.arange(len(traffic)))
    truth_xy, truth_v = human_future(traffic)
    assert np.abs(ch.ego_xy_m - truth_xy).max() < 1e-3  # ADE <= 0.1 m required; the replay is exact
    np.testing.assert_allclose(ch.ego_vxy_mps, truth_v, atol=1e-5)
    # neighbours replay their log, present exactly where the log has them
    fut = slice(T0_INDEX + 1, N_TOTAL)
    np.testing.assert_array_equal(ch.nbr_valid, traffic.nbr_valid[:, :, fut])
    ok = ch.nbr_valid
    assert np.abs(ch.nbr_xy_m[ok] - traffic.nbr_xy_m[:, :, fut][ok]).max() < 1e-3
    assert len(ch.replan_step) == 5 and ch.replan_step.tolist() == [0, 25, 50, 75, 100]
    closed = chunk_metrics(traffic, ch)
    opened = compute_metrics(traffic, truth_xy, truth_v, truth_xy[:, -1])
    assert closed.ade_m.max() < 0.1 and not closed.collision.any() and not ch.sumo_collision.any()
    for name in ("min_ttc_s", "min_box_gap_m", "min_centre_dist_m", "min_ttc2d_s", "max_drac_mps2"):
        np.testing.assert_allclose(getattr(closed, name), getattr(opened, name), rtol=1e-4, atol=1e-3, err_msg=name)
    np.testing.assert_array_equal(closed.collision_2m, opened.collision_2m)


def test_first_plan_equals_the_open_loop_plan_and_later_plans_start_from_the_simulated_ego(
    traffic: ScenarioBatch,
) -> None:
    sub = traffic.take(np.arange(16))
    ch = _run(PlannerSpec.of("sf"), sub, LOG)
    open_loop = make_planner("sf").plan(sub)
    np.testing.assert_allclose(ch.plan_xy_m[:, 0], open_loop.xy_m, atol=1e-3)
    # the ego follows plan r until plan r + 1 is made, from where the ego then was
    for r, step in enumerate(ch.replan_step[1:], start=1):
        np.testing.assert_allclose(ch.ego_xy_m[:, step - 1], ch.plan_xy_m[:, r - 1, step - 1 - ch.replan_step[r - 1]],
                                   atol=1e-6)
        first = ch.plan_xy_m[:, r, 0] - ch.ego_xy_m[:, step - 1]
        assert np.all(np.hypot(*first.T) < 2.5)  # one 0.04 s step from the ego's simulated position
    # replanning changes the outcome: plans after t = 0 differ from the open-loop continuation
    assert not np.allclose(ch.ego_xy_m, open_loop.xy_m, atol=1e-2)


def test_plan_once_is_the_open_loop_plan_in_a_replayed_world(traffic: ScenarioBatch) -> None:
    sub = traffic.take(np.arange(12))
    ch = _run(PlannerSpec.of("idm"), sub, LOG, replan_s=5.0)
    assert ch.replan_step.tolist() == [0] and ch.replan_s == pytest.approx(5.0)
    np.testing.assert_allclose(ch.ego_xy_m, make_planner("idm").plan(sub).xy_m, atol=1e-3)


def test_planners_see_the_simulated_history_and_never_the_future(traffic: ScenarioBatch) -> None:
    sub = traffic.take(np.arange(6))
    blind = RecordingPlanner()
    _run(blind, sub, REACTIVE)
    assert len(blind.seen) == 5
    for view in blind.seen:
        np.testing.assert_allclose(view.ego_xy_m[:, T0_INDEX], 0.0, atol=1e-4)  # re-centred on the ego
        assert np.isnan(view.ego_xy_m[:, T0_INDEX + 1 :]).all()
        assert not view.nbr_valid[:, :, T0_INDEX + 1 :].any()
        assert np.isnan(view.nbr_xy_m[:, :, T0_INDEX + 1 :]).all()
    # markings move with the ego's lateral position only
    later = blind.seen[2]
    shift = later.marking_y_m - sub.marking_y_m
    assert np.allclose(shift, shift[:, :1], atol=1e-4)
    oracle = RecordingPlanner(reads_future=True)
    _run(oracle, sub, LOG)
    view = oracle.seen[1]  # at t = 1 s: the log from there on, re-centred
    assert np.isfinite(view.ego_xy_m[:, T0_INDEX + 1 : T0_INDEX + 100]).all()
    assert np.isnan(view.ego_xy_m[:, T0_INDEX + 101 :]).all()  # beyond the recorded window


def test_replanning_batch_is_a_generic_time_shift_and_translation(traffic: ScenarioBatch) -> None:
    src = traffic.take(np.arange(3))
    k, n = len(src), src.n_neighbours
    sim = SimulatedStates(
        ego_xy_m=src.ego_xy_m.astype(float) + np.array([5.0, 0.5]), ego_vxy_mps=src.ego_vxy_mps.astype(float),
        ego_axy_mps2=src.ego_axy_mps2.astype(float), ego_lane_id=src.ego_lane_id,
        nbr_xy_m=src.nbr_xy_m.astype(float), nbr_vxy_mps=src.nbr_vxy_mps.astype(float),
        nbr_valid=src.nbr_valid, nbr_lane_id=src.nbr_lane_id,
    )  # fmt: skip
    view, centre = replanning_batch(src, sim, T0_INDEX + 25, "none")
    np.testing.assert_allclose(centre, src.ego_xy_m[:, T0_INDEX + 25] + np.array([5.0, 0.5]), atol=1e-5)
    np.testing.assert_allclose(view.ego_xy_m[:, :T0_INDEX + 1], (sim.ego_xy_m[:, 25 : T0_INDEX + 26] - centre[:, None]),
                               atol=1e-4)
    np.testing.assert_allclose(view.marking_y_m, src.marking_y_m - centre[:, 1:2], atol=1e-5)
    assert view.frame0.tolist() == (src.frame0 + 25).tolist()
    assert view.ctx_id.shape == (k, 0)  # context vehicles (future-only truth) never enter a planner's view
    for f in fields(ScenarioBatch):  # every other field keeps its shape and dtype
        if f.name in CONTEXT_FIELDS:
            continue
        assert getattr(view, f.name).shape == getattr(src, f.name).shape, f.name
        assert getattr(view, f.name).dtype == getattr(src, f.name).dtype, f.name
    assert view.nbr_valid.shape == (k, n, N_TOTAL)
    with pytest.raises(ValueError, match="outside"):
        replanning_batch(src, sim, T0_INDEX - 1)


def _brake_scenario(gap_m: float) -> ScenarioBatch:
    """Ego at 30 m/s; a follower in its lane ``gap_m`` bumper to bumper behind at the same speed."""
    follower = VehicleSpec(x0_m=-(gap_m + 4.5), speed_mps=30.0)
    side = VehicleSpec(x0_m=15.0, speed_mps=31.0, lane_offset=1)
    return concat_batches([
        straight_road_scenario(ego_speed_mps=30.0, neighbours=[follower, side], scenario_id=f"brake{i}")
        for i in range(2)
    ])


def test_hard_braking_ego_is_hit_by_a_replayed_follower_but_not_by_a_reactive_one() -> None:
    batch = _brake_scenario(gap_m=25.0)  # 0.83 s headway
    log = _run(BrakePlanner(8.0), batch, LOG)
    reactive = _run(BrakePlanner(8.0), batch, REACTIVE)
    m_log, m_reactive = chunk_metrics(batch, log), chunk_metrics(batch, reactive)
    assert m_log.collision.all() and log.sumo_collision.all()
    assert (m_log.collision_nbr == 0).all()  # the follower (slot 0) hits the ego
    assert not m_reactive.collision.any() and not reactive.sumo_collision.any()
    # the reactive follower braked hard (the log follower kept 30 m/s)
    assert reactive.nbr_vxy_mps[:, 0, -1, 0].max() < 10.0
    assert np.allclose(log.nbr_vxy_mps[:, 0, :, 0], 30.0, atol=1e-4)
    assert np.nanmin(m_reactive.min_box_gap_m) > 0.0


def test_reactive_neighbours_drive_on_with_estimated_parameters(traffic: ScenarioBatch) -> None:
    sub = traffic.take(np.arange(24))
    ch = _run(PlannerSpec.of("human"), sub, REACTIVE)
    fut = slice(T0_INDEX + 1, N_TOTAL)
    present0 = sub.nbr_valid[:, :, T0_INDEX]
    # every neighbour present at t = 0 is simulated to the end (it does not vanish with the camera window)
    assert ch.nbr_valid[present0].all()
    speed = ch.nbr_vxy_mps[..., 0][ch.nbr_valid]
    assert np.all(speed >= 0.0) and np.all(speed < 55.0)
    # they are SUMO-driven: their paths differ from the log, but stay close over 5 s
    log_xy = sub.nbr_xy_m[:, :, fut]
    both = ch.nbr_valid & sub.nbr_valid[:, :, fut]
    err = np.hypot(*(ch.nbr_xy_m[both] - log_xy[both]).T)
    assert err.max() > 0.05 and np.median(err) < 10.0


def test_driver_parameters_from_history() -> None:
    h = 50
    t = np.arange(h) * 0.04
    leader = np.stack([40.0 + 25.0 * t, np.zeros(h)], -1)
    follower = np.stack([40.0 - 4.5 - 25.0 * 1.2 + 25.0 * t, np.zeros(h)], -1)  # 1.2 s behind, bumper to bumper
    alone = np.stack([25.0 * t, np.full(h, 7.5)], -1)
    xy = np.stack([leader, follower, alone])[None]
    vx = np.array([np.full(h, 25.0), np.full(h, 25.0), np.linspace(20.0, 28.0, h)])[None]
    desired, headway = estimate_driver_params(xy, vx, np.ones((1, 3, h), bool), np.full((1, 3), 4.5),
                                              np.full((1, 3), 1.8), DriverModelConfig())
    assert headway[0, 1] == pytest.approx(1.2, abs=1e-6)
    assert headway[0, 0] == headway[0, 2] == DriverModelConfig().default_headway_s
    assert desired[0, 2] == pytest.approx(28.0)


@pytest.mark.slow  # over ~10 s on a loaded 2-core machine (notes/reliability.md)
def test_sumo_collisions_agree_with_the_metric_code(traffic: ScenarioBatch) -> None:
    """Scenario flags agree on rear-end conflicts; every frame where they differ is one of SUMO's two
    documented gaps (``letspi.simulation.engine``): a sideways separation is seen one frame late, and
    a vehicle straddling a lane line is not checked against the other lane's vehicles until its centre
    crosses (or within SUMO's 1 mm tolerance)."""
    for planner, modes in ((BrakePlanner(8.0), (LOG,)), (SwervePlanner(1.5), (LOG, REACTIVE))):
        for mode in modes:
            ch = _run(planner, traffic, mode)
            sb = scored_batch(traffic, ch)
            inp = MetricInputs.from_batch(sb, ch.ego_xy_m, ch.ego_vxy_mps)
            sumo = ch.sumo_contact
            n = sumo.shape[1]  # SUMO simulates the neighbour slots; the metric also scores context vehicles
            metric = boxes_overlap(inp)[:, :n]
            assert metric.any() and sumo.any()
            tol = (np.maximum(np.abs(inp.dx_m) - inp.half_len_sum_m, np.abs(inp.dy_m) - inp.half_wid_sum_m)
                   > -1e-3)[:, :n]
            previous = np.concatenate([np.zeros_like(metric[..., :1]), metric[..., :-1]], axis=-1)
            ego_lane = lane_index_of(sb.marking_y_m, ch.ego_xy_m[..., 1])
            nbr_lane = lane_index_of(sb.marking_y_m, ch.nbr_xy_m[..., 1])
            same_lane = ego_lane[:, None, :] == nbr_lane
            assert not (sumo & ~metric & ~previous & ~tol).any(), (planner, mode)
            assert not (metric & ~sumo & same_lane & ~tol).any(), (planner, mode)
            flags_m, flags_s = metric.any(axis=(1, 2)), sumo.any(axis=(1, 2))
            if isinstance(planner, BrakePlanner):
                np.testing.assert_array_equal(flags_m, flags_s)
                # the scored collision also counts context vehicles, which SUMO does not simulate: a superset
                scored = chunk_metrics(traffic, ch).collision
                assert (scored >= ch.sumo_collision).all()
            else:
                assert (flags_m == flags_s).mean() >= 0.9


def test_unusable_plans_are_flagged_and_the_ego_keeps_its_velocity(traffic: ScenarioBatch) -> None:
    sub = traffic.take(np.arange(3))
    ch = _run(WildPlanner(), sub, REACTIVE)
    assert ch.plan_nonfinite.tolist() == [True, True, False]
    v0 = sub.ego_vxy_mps[:2, T0_INDEX].astype(float)
    np.testing.assert_allclose(ch.ego_vxy_mps[:2], np.broadcast_to(v0[:, None], (2, 125, 2)), atol=1e-4)
    assert np.isfinite(ch.ego_xy_m).all()
    metrics = chunk_metrics(sub, ch)
    assert metrics.finite.all()  # what the ego did is scored; the flag says it was not the plan


def test_traci_backend_gives_the_libsumo_result(traffic: ScenarioBatch) -> None:
    """The socket backend (needed for sumo-gui) drives a SUMO subprocess through the same code."""
    sub = traffic.take(np.arange(3))
    fast = _run(PlannerSpec.of("idm"), sub, REACTIVE)
    slow = _run(PlannerSpec.of("idm"), sub, REACTIVE, config=ClosedLoopConfig(sumo_backend="traci"))
    np.testing.assert_allclose(slow.ego_xy_m, fast.ego_xy_m, atol=1e-9)
    np.testing.assert_array_equal(slow.nbr_valid, fast.nbr_valid)
    np.testing.assert_allclose(slow.nbr_xy_m[slow.nbr_valid], fast.nbr_xy_m[fast.nbr_valid], atol=1e-9)


def test_libsumo_and_pyarrow_share_a_process(tmp_path: Path, traffic: ScenarioBatch) -> None:
    ch = _run(PlannerSpec.of("cv"), traffic.take(np.arange(2)), LOG)  # libsumo is loaded in this process now
    frame = pd.DataFrame({"scenario_id": ch.scenario_id.astype(str), "x": ch.ego_xy_m[:, -1, 0]})
    frame.to_parquet(tmp_path / "a.parquet")
    pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "a.parquet"), frame)


def test_configuration_errors_are_clear() -> None:
    with pytest.raises(ValueError, match="closed-loop-log, closed-loop-reactive"):
        ClosedLoopConfig(mode="open-loop")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="replan_s"):
        ClosedLoopConfig(planner_replan_s={"sf": 0.0})
    with pytest.raises(ValueError, match="--workers must be >= 0"):
        ClosedLoopConfig(workers=-1)
    assert ClosedLoopConfig(sumo_gui=True).sumo_backend == "traci"
    own = ClosedLoopConfig(replan_s=0.5, planner_replan_s={"slow": 2.0})
    assert own.for_planner("slow").replan_s == 2.0 and own.for_planner("sf") is own
    with pytest.raises(ValueError, match="replan_s"):
        ClosedLoopConfig(replan_s=6.0)
    with pytest.raises(TypeError, match="planner_spec"):
        list(run_closed_loop("sf", _brake_scenario(25.0)))  # type: ignore[arg-type]
