"""``letspi export commonroad``: round trip through commonroad-io, and CommonRoad's collision checker on
exported plans against letspi's collision metric. Skipped without the ``commonroad`` extra."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.physics import synthetic_batch
from letspi.constants import N_FUTURE, T0_INDEX
from letspi.metrics.compute import compute_metrics
from letspi.planners.cv import ConstantVelocityPlanner
from letspi.planners.frenet import FrenetPlanner
from letspi.scenario.build import LANE_WIDTH_M, VehicleSpec, straight_road_scenario
from letspi.scenario.types import concat_batches

pytest.importorskip("commonroad", reason="the commonroad extra of letspi-interop is not installed")
pytest.importorskip("letspi_interop", reason="letspi-interop is not installed (pip install -e packages/letspi-interop)")
from letspi_interop import commonroad as cr


def _scenes():
    """A lane change left of the ego, a vehicle appearing at t = 1 s, a truck, a context vehicle."""
    nbrs = [VehicleSpec(x0_m=35.0, speed_mps=24.0, accel_mps2=-1.5), VehicleSpec(x0_m=-20.0, speed_mps=33.0,
            lane_offset=1, y_offset_m=-0.4), VehicleSpec(x0_m=60.0, speed_mps=22.0, lane_offset=-1,
            vehicle_class=1, length_m=16.0, width_m=2.5), VehicleSpec(x0_m=-70.0, speed_mps=36.0,
            visible_from_index=T0_INDEX + 25)]
    a = straight_road_scenario(ego_speed_mps=30.0, neighbours=nbrs, context=[VehicleSpec(x0_m=120.0, speed_mps=20.0)],
                               scenario_id="cr-a")
    b = straight_road_scenario(ego_speed_mps=20.0, ego_accel_mps2=0.5, n_lanes=2, ego_lane_index=0,
                               neighbours=[VehicleSpec(x0_m=15.0, speed_mps=20.0, lane_offset=1)], scenario_id="cr-b")
    return concat_batches([a, b])


def test_scenarios_read_back_with_positions_sizes_and_times(tmp_path):
    batch = _scenes()
    plan = FrenetPlanner().plan(batch.history())
    plans = {"frenet": {str(s): (plan.xy_m[k], plan.vxy_mps[k]) for k, s in enumerate(batch.scenario_id)}}
    written = cr.export(batch, tmp_path, plans=plans)
    assert sorted(p.name for p in written) == ["cr-a.frenet.solution.xml", "cr-a.xml", "cr-b.frenet.solution.xml",
                                               "cr-b.xml"]
    for k in range(len(batch)):
        scenario, problems = cr.read(tmp_path / f"{batch.scenario_id[k]}.xml")
        assert scenario.dt == pytest.approx(0.04)
        expected = {t.obstacle_id: t for t in cr.recorded_tracks(batch, k)}
        got = {o.obstacle_id: o for o in scenario.dynamic_obstacles}
        assert set(got) == set(expected) and len(got) == (5 if k == 0 else 1)  # 4 + 1 context; 1
        for oid, track in expected.items():
            obstacle = got[oid]
            assert obstacle.obstacle_shape.length == pytest.approx(track.length_m, abs=1e-4)
            assert obstacle.obstacle_shape.width == pytest.approx(track.width_m, abs=1e-4)
            states = [obstacle.initial_state, *(obstacle.prediction.trajectory.state_list if obstacle.prediction
                                                else [])]
            assert [s.time_step for s in states] == list(track.time_steps)
            xy = np.array([s.position for s in states])
            assert np.abs(xy - track.xy_m).max() <= 1e-3  # positions to 1 mm
        # the road: one lanelet per lane, bounded by the markings
        marks = batch.marking_y_m[k][np.isfinite(batch.marking_y_m[k])]
        lanelets = sorted(scenario.lanelet_network.lanelets, key=lambda ll: ll.lanelet_id)
        assert len(lanelets) == len(marks) - 1
        for j, ll in enumerate(lanelets):
            assert np.allclose(ll.right_vertices[:, 1], marks[j], atol=1e-4)
            assert np.allclose(ll.left_vertices[:, 1], marks[j + 1], atol=1e-4)
        problem = problems.planning_problem_dict[cr.EGO_PROBLEM_ID]
        assert problem.initial_state.time_step == 0
        assert problem.initial_state.velocity == pytest.approx(float(np.hypot(*batch.ego_vxy_mps[k, T0_INDEX])),
                                                               abs=1e-3)
        goal = problem.goal.state_list[0]
        human_end = batch.ego_xy_m[k, T0_INDEX + N_FUTURE]
        assert goal.position.contains_point(np.asarray(human_end, dtype=np.float64))
        assert goal.time_step.start == goal.time_step.end == N_FUTURE
    # the lane change of neighbour slot 1 (left lane, 0.4 m right of its centre) survives the trip
    scenario, _ = cr.read(tmp_path / "cr-a.xml")
    lc = next(o for o in scenario.dynamic_obstacles if o.obstacle_id == cr.NEIGHBOUR_ID0 + 1)
    assert lc.initial_state.position[1] == pytest.approx(LANE_WIDTH_M - 0.4, abs=1e-3)
    # the late vehicle starts when it appears, one second after t = 0
    late = next(o for o in scenario.dynamic_obstacles if o.obstacle_id == cr.NEIGHBOUR_ID0 + 3)
    assert late.initial_state.time_step == 25


def test_solutions_hold_the_plans(tmp_path):
    from commonroad.common.solution import CommonRoadSolutionReader

    batch = _scenes()
    plan = FrenetPlanner().plan(batch.history())
    plans = {"frenet": {str(s): (plan.xy_m[k], plan.vxy_mps[k]) for k, s in enumerate(batch.scenario_id)}}
    cr.export(batch, tmp_path, plans=plans)
    solution = CommonRoadSolutionReader.open(str(tmp_path / "cr-a.frenet.solution.xml"))
    states = solution.planning_problem_solutions[0].trajectory.state_list
    assert [s.time_step for s in states] == list(range(N_FUTURE + 1))
    xy = np.array([s.position for s in states[1:]])
    assert np.abs(xy - plan.xy_m[0]).max() <= 1e-3
    assert np.abs(np.array([s.velocity_y for s in states[1:]]) - plan.vxy_mps[0, :, 1]).max() <= 1e-3


def test_commonroad_collision_checker_finds_the_collisions_letspi_finds():
    dc = pytest.importorskip("commonroad_dc.collision.collision_detection.pycrcc_collision_dispatch",
                             reason="CommonRoad's drivability checker is not installed")
    batch = concat_batches([synthetic_batch(60, seed=2), _scenes()])
    planners = (ConstantVelocityPlanner(), FrenetPlanner())
    agree = 0
    n_collisions = 0
    for planner in planners:
        plan = planner.plan(batch.history())
        ours = compute_metrics(batch, plan.xy_m, plan.vxy_mps).collision
        for k in range(len(batch)):
            scenario, _ = cr.to_commonroad(batch, k, orientation="axis_aligned", extra_xy_m=plan.xy_m[k])
            checker = dc.create_collision_checker(scenario)
            ego = cr.plan_obstacle(batch, k, plan.xy_m[k], plan.vxy_mps[k], orientation="axis_aligned")
            theirs = checker.collide(dc.create_collision_object(ego.prediction))
            agree += int(theirs == bool(ours[k]))
            n_collisions += int(ours[k])
    assert n_collisions >= 5  # the comparison covers both outcomes
    assert agree == len(planners) * len(batch)
