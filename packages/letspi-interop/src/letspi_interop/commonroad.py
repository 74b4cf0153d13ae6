"""Export scenarios and plans to CommonRoad files with ``commonroad-io`` (extra ``commonroad``, imported here).

One letspi scenario is one CommonRoad scenario in its ego frame (right-handed, metres), time step 0 = t = 0,
dt = 0.04 s: one lanelet per lane of the ego's carriageway (right to left, ids 1..L, straight along x over every
exported trajectory plus ``road_margin_m``; adjacent lanelets linked; outer markings solid, inner dashed); the
neighbours (ids 100 + slot) and context vehicles (200 + slot) as dynamic obstacles with their *recorded* futures
(the first contiguous run of recorded frames); the ego as the planning problem (id 1), its goal the region the
success test accepts at step 125: the human endpoint ± max(5 m, 10 % of its progress) along x, the width of
the human's final lane. Orientation ``heading`` = atan2(vy, vx); ``axis_aligned`` = 0 keeps letspi's geometry
exactly, so a CommonRoad collision check sees the boxes letspi scores. Plans become point-mass *solutions*
(steps 0..125), one file per scenario and planner.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from commonroad.common.file_reader import CommonRoadFileReader
from commonroad.common.file_writer import CommonRoadFileWriter, OverwriteExistingFile
from commonroad.common.solution import (
    CommonRoadSolutionWriter,
    CostFunction,
    PlanningProblemSolution,
    Solution,
    VehicleModel,
    VehicleType,
)
from commonroad.common.util import Interval
from commonroad.geometry.shape import Rectangle
from commonroad.planning.goal import GoalRegion
from commonroad.planning.planning_problem import PlanningProblem, PlanningProblemSet
from commonroad.prediction.prediction import TrajectoryPrediction
from commonroad.scenario.lanelet import Lanelet, LaneletType, LineMarking
from commonroad.scenario.obstacle import DynamicObstacle, ObstacleType
from commonroad.scenario.scenario import Location, Scenario, ScenarioID, Tag
from commonroad.scenario.state import CustomState, InitialState, PMState
from commonroad.scenario.trajectory import Trajectory

from letspi.constants import DT_S, N_FUTURE, T0_INDEX
from letspi.metrics.config import MetricsConfig
from letspi.scenario.types import VEHICLE_CLASS_TRUCK, ScenarioBatch

Orientation = Literal["heading", "axis_aligned"]
ORIENTATIONS: tuple[str, ...] = ("heading", "axis_aligned")
EGO_PROBLEM_ID = 1
NEIGHBOUR_ID0 = 100
CONTEXT_ID0 = 200
DECIMALS = 4  # positions written to 0.1 mm
AUTHOR = "letspi"
SOURCE = "letspi export commonroad (HighD-format recording)"


@dataclass(frozen=True)
class Track:
    """One exported vehicle: id, class, size and its states at ``time_steps`` (K,): xy (K, 2), vxy (K, 2)."""

    obstacle_id: int
    vehicle_class: int
    length_m: float
    width_m: float
    time_steps: np.ndarray
    xy_m: np.ndarray
    vxy_mps: np.ndarray


def _first_run(valid: np.ndarray) -> np.ndarray:
    """Indices of the first contiguous run of True in ``valid`` (1-D), empty if none."""
    idx = np.flatnonzero(valid)
    if not len(idx):
        return idx
    breaks = np.flatnonzero(np.diff(idx) != 1)
    return idx[: breaks[0] + 1] if len(breaks) else idx


def recorded_tracks(batch: ScenarioBatch, index: int) -> list[Track]:
    """The neighbours (t = 0 and the recorded future) and context vehicles of scenario ``index``."""
    if not batch.has_future:
        raise ValueError("exporting recorded futures needs the full scenarios, not a history-only view")
    tracks: list[Track] = []
    frames = slice(T0_INDEX, T0_INDEX + N_FUTURE + 1)  # time steps 0..125
    for slot in range(batch.n_neighbours):
        xy = batch.nbr_xy_m[index, slot, frames].astype(np.float64)
        vxy = batch.nbr_vxy_mps[index, slot, frames].astype(np.float64)
        ok = batch.nbr_valid[index, slot, frames] & np.isfinite(xy).all(axis=1) & np.isfinite(vxy).all(axis=1)
        run = _first_run(ok)
        if len(run) >= 1:
            tracks.append(Track(NEIGHBOUR_ID0 + slot, int(batch.nbr_class[index, slot]),
                                float(batch.nbr_length_m[index, slot]), float(batch.nbr_width_m[index, slot]),
                                run, xy[run], vxy[run]))
    for slot in range(batch.ctx_id.shape[1]):
        xy = batch.ctx_xy_m[index, slot].astype(np.float64)
        vxy = batch.ctx_vxy_mps[index, slot].astype(np.float64)
        ok = batch.ctx_valid[index, slot] & np.isfinite(xy).all(axis=1) & np.isfinite(vxy).all(axis=1)
        run = _first_run(ok)
        if len(run) >= 1:
            tracks.append(Track(CONTEXT_ID0 + slot, int(batch.ctx_class[index, slot]),
                                float(batch.ctx_length_m[index, slot]), float(batch.ctx_width_m[index, slot]),
                                run + 1, xy[run], vxy[run]))  # context frame f is time step f + 1
    return tracks


def _orientation(vxy: np.ndarray, mode: Orientation) -> np.ndarray:
    if mode == "axis_aligned":
        return np.zeros(len(vxy))
    return np.arctan2(vxy[:, 1], np.maximum(vxy[:, 0], 1e-6))


def _obstacle(track: Track, mode: Orientation) -> DynamicObstacle:
    shape = Rectangle(length=track.length_m, width=track.width_m)
    heading = _orientation(track.vxy_mps, mode)
    speed = np.hypot(track.vxy_mps[:, 0], track.vxy_mps[:, 1])
    states = [CustomState(position=track.xy_m[k].copy(), orientation=float(heading[k]), velocity=float(speed[k]),
                          time_step=int(track.time_steps[k])) for k in range(len(track.time_steps))]
    init = InitialState(position=states[0].position, orientation=states[0].orientation, velocity=states[0].velocity,
                        acceleration=0.0, yaw_rate=0.0, slip_angle=0.0, time_step=states[0].time_step)
    prediction = (TrajectoryPrediction(Trajectory(states[1].time_step, states[1:]), shape) if len(states) > 1
                  else None)
    kind = ObstacleType.TRUCK if track.vehicle_class == VEHICLE_CLASS_TRUCK else ObstacleType.CAR
    return DynamicObstacle(track.obstacle_id, kind, shape, init, prediction)


def _lanelets(marking_y_m: np.ndarray, marking_is_edge: np.ndarray, x_lo_m: float, x_hi_m: float) -> list[Lanelet]:
    marks = marking_y_m[np.isfinite(marking_y_m)].astype(np.float64)
    edges = marking_is_edge[: len(marks)]
    n_lanes = len(marks) - 1
    x = np.linspace(x_lo_m, x_hi_m, max(2, int(np.ceil((x_hi_m - x_lo_m) / 20.0)) + 1))
    out = []
    for k in range(n_lanes):
        right = np.stack([x, np.full_like(x, marks[k])], axis=1)
        left = np.stack([x, np.full_like(x, marks[k + 1])], axis=1)
        out.append(Lanelet(
            left_vertices=left, center_vertices=0.5 * (left + right), right_vertices=right, lanelet_id=k + 1,
            adjacent_left=k + 2 if k + 1 < n_lanes else None, adjacent_left_same_direction=True if k + 1 < n_lanes
            else None, adjacent_right=k if k > 0 else None, adjacent_right_same_direction=True if k > 0 else None,
            line_marking_left_vertices=LineMarking.SOLID if edges[k + 1] else LineMarking.DASHED,
            line_marking_right_vertices=LineMarking.SOLID if edges[k] else LineMarking.DASHED,
            lanelet_type={LaneletType.HIGHWAY, LaneletType.MAIN_CARRIAGE_WAY}))
    return out


def scenario_id_of(batch: ScenarioBatch, index: int) -> ScenarioID:
    """``ZAM_LetsPi-<recording>_<ego id>_T-<frame at t = 0>`` (ZAM: CommonRoad's code for made-up maps)."""
    return ScenarioID(country_id="ZAM", map_name="LetsPi", map_id=max(int(batch.recording_id[index]), 1),
                      configuration_id=int(batch.ego_id[index]), obstacle_behavior="T",
                      prediction_id=int(batch.frame0[index]))


def goal_region(batch: ScenarioBatch, index: int, config: MetricsConfig | None = None) -> GoalRegion:
    """Where the success test accepts the plan's end (module doc)."""
    cfg = config or MetricsConfig()
    x0 = float(batch.ego_xy_m[index, T0_INDEX, 0])
    end = batch.ego_xy_m[index, T0_INDEX + N_FUTURE].astype(np.float64)
    tol = max(cfg.sr_progress_tol_m, cfg.sr_progress_tol_rel * abs(float(end[0]) - x0))
    marks = batch.marking_y_m[index][np.isfinite(batch.marking_y_m[index])].astype(np.float64)
    k = int(np.clip(np.searchsorted(marks, end[1]) - 1, 0, max(len(marks) - 2, 0)))
    lane = (marks[k], marks[k + 1]) if len(marks) >= 2 else (end[1] - 1.875, end[1] + 1.875)
    centre = np.array([end[0], 0.5 * (lane[0] + lane[1])])
    area = Rectangle(length=2.0 * tol, width=float(lane[1] - lane[0]), center=centre, orientation=0.0)
    return GoalRegion([CustomState(time_step=Interval(N_FUTURE, N_FUTURE), position=area)])


def to_commonroad(batch: ScenarioBatch, index: int, *, orientation: Orientation = "heading",
                  road_margin_m: float = 50.0, extra_xy_m: np.ndarray | None = None,
                  ) -> tuple[Scenario, PlanningProblemSet]:
    """Scenario ``index`` of ``batch`` (with its recorded future) as a CommonRoad scenario and planning problem;
    ``extra_xy_m`` (..., 2): more positions (e.g. plans) the road must cover.
    """
    if orientation not in ORIENTATIONS:
        raise ValueError(f"orientation must be one of {ORIENTATIONS}, got {orientation!r}")
    tracks = recorded_tracks(batch, index)
    ego_xy = batch.ego_xy_m[index, T0_INDEX:].astype(np.float64)
    xs = [ego_xy[:, 0], *(t.xy_m[:, 0] for t in tracks)]
    if extra_xy_m is not None:
        xs.append(np.asarray(extra_xy_m, dtype=np.float64).reshape(-1, 2)[:, 0])
    x_all = np.concatenate(xs)
    x_all = x_all[np.isfinite(x_all)]
    scenario = Scenario(dt=DT_S, scenario_id=scenario_id_of(batch, index), author=AUTHOR, source=SOURCE,
                        tags={Tag.HIGHWAY, Tag.MULTI_LANE})
    for lanelet in _lanelets(batch.marking_y_m[index], batch.marking_is_edge[index],
                             float(x_all.min()) - road_margin_m, float(x_all.max()) + road_margin_m):
        scenario.lanelet_network.add_lanelet(lanelet)
    for track in tracks:
        scenario.add_objects(_obstacle(track, orientation))
    v0 = batch.ego_vxy_mps[index, T0_INDEX].astype(np.float64)
    init = InitialState(position=batch.ego_xy_m[index, T0_INDEX].astype(np.float64),
                        orientation=float(_orientation(v0[None], orientation)[0]), velocity=float(np.hypot(*v0)),
                        acceleration=float(batch.ego_axy_mps2[index, T0_INDEX, 0]), yaw_rate=0.0, slip_angle=0.0,
                        time_step=0)
    problem = PlanningProblem(EGO_PROBLEM_ID, init, goal_region(batch, index))
    return scenario, PlanningProblemSet([problem])


def plan_solution(scenario_id: ScenarioID, xy0_m: np.ndarray, vxy0_mps: np.ndarray, plan_xy_m: np.ndarray,
                  plan_vxy_mps: np.ndarray) -> Solution:
    """A plan (F, 2) positions / velocities after the t = 0 state (xy0, vxy0) as a point-mass solution."""
    xy = np.concatenate([np.asarray(xy0_m, dtype=np.float64)[None], np.asarray(plan_xy_m, dtype=np.float64)])
    vxy = np.concatenate([np.asarray(vxy0_mps, dtype=np.float64)[None], np.asarray(plan_vxy_mps, dtype=np.float64)])
    states = [PMState(time_step=k, position=xy[k].copy(), velocity=float(vxy[k, 0]), velocity_y=float(vxy[k, 1]))
              for k in range(len(xy))]
    pps = PlanningProblemSolution(planning_problem_id=EGO_PROBLEM_ID, vehicle_model=VehicleModel.PM,
                                  vehicle_type=VehicleType.BMW_320i, cost_function=CostFunction.WX1,
                                  trajectory=Trajectory(0, states))
    return Solution(scenario_id, [pps])


def plan_obstacle(batch: ScenarioBatch, index: int, plan_xy_m: np.ndarray, plan_vxy_mps: np.ndarray,
                  orientation: Orientation = "heading", obstacle_id: int = 999) -> DynamicObstacle:
    """The ego following a plan (F, 2) as a dynamic obstacle (time steps 1..F): what CommonRoad's
    collision checker takes."""
    track = Track(obstacle_id, int(batch.ego_class[index]), float(batch.ego_length_m[index]),
                  float(batch.ego_width_m[index]), np.arange(0, len(plan_xy_m) + 1),
                  np.concatenate([batch.ego_xy_m[index, T0_INDEX][None].astype(np.float64), plan_xy_m]),
                  np.concatenate([batch.ego_vxy_mps[index, T0_INDEX][None].astype(np.float64), plan_vxy_mps]))
    return _obstacle(track, orientation)


def file_name(batch: ScenarioBatch, index: int) -> str:
    return f"{batch.scenario_id[index]}.xml"


def export(batch: ScenarioBatch, out_dir: Path, *, plans: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]]
           | None = None, orientation: Orientation = "heading") -> list[Path]:
    """Write every scenario of ``batch`` (and, per planner name, its plans: scenario id -> (xy, vxy)) to
    ``out_dir``: ``<scenario id>.xml`` and ``<scenario id>.<planner>.solution.xml``. Returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    plans = plans or {}
    for k in range(len(batch)):
        sid = str(batch.scenario_id[k])
        own = [p[sid] for p in plans.values() if sid in p]
        extra = np.concatenate([xy for xy, _ in own]) if own else None
        scenario, problems = to_commonroad(batch, k, orientation=orientation, extra_xy_m=extra)
        path = out / file_name(batch, k)
        CommonRoadFileWriter(scenario, problems, author=AUTHOR, affiliation="", source=SOURCE,
                             tags=scenario.tags, location=Location(), decimal_precision=DECIMALS).write_to_file(
            str(path), OverwriteExistingFile.ALWAYS)
        written.append(path)
        for planner, by_id in plans.items():
            if sid not in by_id:
                continue
            xy, vxy = by_id[sid]
            solution = plan_solution(scenario.scenario_id, batch.ego_xy_m[k, T0_INDEX], batch.ego_vxy_mps[k, T0_INDEX],
                                     xy, vxy)
            name = f"{sid}.{planner}.solution.xml"
            CommonRoadSolutionWriter(solution).write_to_file(str(out), name, overwrite=True)
            written.append(out / name)
    return written


def read(path: Path) -> tuple[Scenario, PlanningProblemSet]:
    """A scenario file read back with commonroad-io."""
    return CommonRoadFileReader(str(path)).open()
