"""The closed-loop simulation of one chunk: K scenarios side by side in one SUMO network, in lockstep.

Per scenario, one road (slot) carries the ego and its neighbours (the batch's neighbour slots).
Frame by frame (0.04 s), over the scenario's 200 frames:

* history (frames 0..74): every vehicle is placed on its recorded position (``moveToXY``,
  keepRoute 2: exact position, lateral offset included), inserted when it appears in the log and
  removed when it leaves it;
* at t = 0 and every ``replan_s`` after it the planner sees a batch built from the simulated
  history (``letspi.simulation.replan``), all K scenarios in one call (split by the planner's
  ``batch_size``); the ego then follows the plan frame by frame until the next replan;
* ``closed-loop-log``: the neighbours keep replaying the log; ``closed-loop-reactive``: at t = 0
  they are released to SUMO (IDM + SL2015, desired speed and headway from their history); vehicles
  that enter the log later are inserted at their recorded state and released one frame after.

Geometry convention shared with the metrics: vehicles are axis-aligned boxes; SUMO's front bumper
is the box centre plus half a length along x (SUMO's own collision check works in lane
coordinates, i.e. on the same boxes). A vehicle is inserted one frame before it is recorded (at its
back-extrapolated position), because SUMO does not check collisions in a vehicle's insertion step.
Collisions are read from ``simulation.getCollisions()`` (``--collision.mingap-factor 0``: contact
only; ``--collision.action warn``: nobody is removed, an overlap is reported every frame it lasts).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from letspi.constants import DT_S, N_TOTAL, T0_INDEX
from letspi.planners.base import PlanBatch, Planner
from letspi.scenario.types import ScenarioBatch
from letspi.simulation.config import OFF_ROAD_MARGIN_M, ClosedLoopConfig, ClosedLoopMode
from letspi.simulation.drivers import estimate_driver_params
from letspi.simulation.network import VTYPE_ID, SlotNetwork, layout_keys
from letspi.simulation.replan import FuturePolicy, SimulatedStates, lane_ids_from_y, replanning_batch
from letspi.simulation.result import ClosedLoopChunk
from letspi.simulation.session import SumoSession

SPEED_MODE_ALL_CHECKS = 31
LANE_CHANGE_MODE_NONE = 0
LANE_CHANGE_MODE_DEFAULT = 1621
MIN_HEADING_SPEED_MPS = 0.5


def replan_frames_of(replan_every: int) -> list[int]:
    """Frames (source indexing) at which plans are made: t = 0, then every ``replan_every``."""
    return list(range(T0_INDEX, N_TOTAL - 1, replan_every))


def plan_in_batches(planner: Planner, batch: ScenarioBatch) -> PlanBatch:
    """``planner.plan`` over ``batch`` in sub-batches of ``planner.batch_size``."""
    step = max(1, int(planner.batch_size))
    if len(batch) <= step:
        return planner.plan(batch)
    parts = [planner.plan(batch.take(slice(s, s + step))) for s in range(0, len(batch), step)]
    info_keys = set.intersection(*(set(p.info) for p in parts))
    return PlanBatch(
        xy_m=np.concatenate([p.xy_m for p in parts]),
        vxy_mps=np.concatenate([p.vxy_mps for p in parts]),
        goals_xy_m=np.concatenate([p.goals_xy_m for p in parts]),
        info={k: np.concatenate([np.asarray(p.info[k]) for p in parts]) for k in sorted(info_keys)},
    )


class _Group:
    """Bookkeeping of one lockstep simulation: V = K * (1 + N) vehicles, ego of scenario k at k * (1 + N)."""

    def __init__(self, batch: ScenarioBatch, net: SlotNetwork, prefix: str) -> None:
        k, n = len(batch), batch.n_neighbours
        self.k, self.n, self.per = k, n, 1 + n
        v = k * self.per
        self.batch = batch
        self.scn = np.repeat(np.arange(k), self.per)
        self.nbr_slot = np.tile(np.arange(-1, n), k)
        self.is_ego = self.nbr_slot < 0
        self.ego_rows = np.flatnonzero(self.is_ego)
        self.nbr_rows = np.flatnonzero(~self.is_ego)
        self.length = np.concatenate([batch.ego_length_m[:, None], batch.nbr_length_m], axis=1).reshape(v).astype(float)
        self.width = np.concatenate([batch.ego_width_m[:, None], batch.nbr_width_m], axis=1).reshape(v).astype(float)
        ego_xy = batch.ego_xy_m.astype(np.float64)[:, None]
        self.log_xy = np.concatenate([ego_xy, batch.nbr_xy_m.astype(np.float64)], axis=1).reshape(v, N_TOTAL, 2)
        ego_v = batch.ego_vxy_mps.astype(np.float64)[:, None]
        self.log_vxy = np.concatenate([ego_v, batch.nbr_vxy_mps.astype(np.float64)], axis=1).reshape(v, N_TOTAL, 2)
        ego_valid = np.isfinite(batch.ego_xy_m).all(axis=-1)[:, None]
        valid = np.concatenate([ego_valid, batch.nbr_valid], axis=1).reshape(v, N_TOTAL)
        self.log_valid = valid & np.isfinite(self.log_xy).all(axis=-1) & np.isfinite(self.log_vxy).all(axis=-1)
        self.log_lane = np.concatenate([batch.ego_lane_id[:, None], batch.nbr_lane_id], axis=1).reshape(v, N_TOTAL)
        slots = np.arange(k)
        self.x_off = np.full(v, net.x_origin_m)
        self.y_off = np.repeat(net.y_offset_m(slots, batch.marking_y_m), self.per)
        self.route = [net.route_id(int(s)) for s in self.scn]
        self.prefix = prefix
        self.generation = np.zeros(v, dtype=np.int64)
        self.sumo_id: list[str] = [""] * v
        self.present = np.zeros(v, dtype=bool)
        self.released = np.zeros(v, dtype=bool)
        self.rec_xy = np.full((v, N_TOTAL, 2), np.nan)
        self.rec_vxy = np.full((v, N_TOTAL, 2), np.nan)
        self.rec_valid = np.zeros((v, N_TOTAL), dtype=bool)
        self.rec_lane = self.log_lane.copy()
        self.ego_axy = batch.ego_axy_mps2.astype(np.float64).copy()
        self.cmd_xy = np.full((k, N_TOTAL, 2), np.nan)
        self.cmd_vxy = np.full((k, N_TOTAL, 2), np.nan)

    def states(self) -> SimulatedStates:
        k, n = self.k, self.n
        rec_lane = self.rec_lane.reshape(k, self.per, N_TOTAL)
        xy = self.rec_xy.reshape(k, self.per, N_TOTAL, 2)
        vxy = self.rec_vxy.reshape(k, self.per, N_TOTAL, 2)
        valid = self.rec_valid.reshape(k, self.per, N_TOTAL)
        return SimulatedStates(
            ego_xy_m=xy[:, 0],
            ego_vxy_mps=vxy[:, 0],
            ego_axy_mps2=self.ego_axy,
            ego_lane_id=rec_lane[:, 0],
            nbr_xy_m=xy[:, 1:],
            nbr_vxy_mps=vxy[:, 1:],
            nbr_valid=valid[:, 1:].reshape(k, n, N_TOTAL),
            nbr_lane_id=rec_lane[:, 1:],
        )


def _front_and_angle(
    xy: np.ndarray, vxy: np.ndarray, length: np.ndarray, x_off: np.ndarray, y_off: np.ndarray
) -> tuple[list[float], list[float], list[float]]:
    """SUMO front-bumper X, Y and navigational angle [deg] of box centres (V', 2)."""
    x = xy[:, 0] + 0.5 * length + x_off
    y = xy[:, 1] + y_off
    fast = np.hypot(vxy[:, 0], vxy[:, 1]) > MIN_HEADING_SPEED_MPS
    heading = np.where(fast, np.arctan2(vxy[:, 1], vxy[:, 0]), 0.0)
    angle = 90.0 - np.degrees(heading)  # cosmetic (GUI): SUMO keeps lane-aligned boxes
    return x.tolist(), y.tolist(), angle.tolist()


def simulate_group(
    session: SumoSession,
    planner: Planner,
    batch: ScenarioBatch,
    config: ClosedLoopConfig,
    *,
    replan_every: int,
    future: FuturePolicy,
    run_tag: str = "g",
) -> ClosedLoopChunk:
    """Simulate K scenarios of one lane layout together (module doc). ``indices`` are 0..K-1."""
    t_start = time.perf_counter()
    cpu_start = time.process_time()
    widths = set(layout_keys(batch.marking_y_m))
    if len(widths) != 1:
        raise ValueError(f"simulate_group needs one lane layout, got {len(widths)}")
    net = session.open(widths.pop(), max(len(batch), config.chunk_size))
    api: Any = session.api
    tc = api.constants
    sub_vars = (tc.VAR_POSITION, tc.VAR_SPEED)
    g = _Group(batch, net, run_tag)
    reactive = config.mode == ClosedLoopMode.REACTIVE
    id_to_row: dict[str, int] = {}
    replans = replan_frames_of(replan_every)
    n_future = N_TOTAL - T0_INDEX - 1
    plans_xy = np.full((g.k, len(replans), n_future, 2), np.nan)
    goals_xy = np.full((g.k, len(replans), 2), np.nan)
    info: dict[str, np.ndarray] = {}
    nonfinite = np.zeros(g.k, dtype=bool)
    contact = np.zeros((g.k, g.n, n_future), dtype=bool)
    nbr_collisions = np.zeros(g.k, dtype=np.int64)
    plan_s = 0.0
    lengths = g.length.tolist()
    widths_v = g.width.tolist()
    road_y = np.stack([np.nanmin(batch.marking_y_m, axis=1), np.nanmax(batch.marking_y_m, axis=1)], axis=1)

    for f in range(N_TOTAL):
        # --- who is driven how in this frame -----------------------------------------------
        if reactive and f > T0_INDEX:
            _release(api, g, f, config)
        if f <= T0_INDEX:
            log_driven = np.ones_like(g.is_ego)
        else:  # the ego follows its plan; reactive neighbours replay only until released
            log_driven = ~g.is_ego & ~g.released if reactive else ~g.is_ego
        want_log = log_driven & g.log_valid[:, f]
        nxt = g.log_valid[:, f + 1] if f + 1 < N_TOTAL else np.zeros_like(want_log)
        preroll = log_driven & ~want_log & nxt & ~g.present
        plan_driven = g.is_ego & (f > T0_INDEX)
        to_remove = np.flatnonzero(g.present & log_driven & ~want_log & ~preroll)
        to_add = np.flatnonzero((want_log | preroll | plan_driven) & ~g.present)

        for r in to_remove.tolist():
            api.vehicle.unsubscribe(g.sumo_id[r])  # libsumo fails the next step on a removed subscriber
            api.vehicle.remove(g.sumo_id[r])
            del id_to_row[g.sumo_id[r]]
            g.present[r] = False
        for r in to_add.tolist():
            vid = f"{g.prefix}.{r}.{int(g.generation[r])}"
            g.generation[r] += 1
            api.vehicle.add(vid, g.route[r], VTYPE_ID, depart="now")
            api.vehicle.setLength(vid, lengths[r])
            api.vehicle.setWidth(vid, widths_v[r])
            api.vehicle.setSpeedMode(vid, 0)
            api.vehicle.setLaneChangeMode(vid, LANE_CHANGE_MODE_NONE)
            api.vehicle.subscribe(vid, sub_vars)
            g.sumo_id[r] = vid
            id_to_row[vid] = r
            g.present[r] = True

        # --- commands ------------------------------------------------------------------------
        rows_log = np.flatnonzero(want_log | preroll)
        if rows_log.size:
            xy = g.log_xy[rows_log, f].copy()
            vxy = g.log_vxy[rows_log, f].copy()
            pre = preroll[rows_log]
            if pre.any():
                xy[pre] = g.log_xy[rows_log[pre], f + 1] - g.log_vxy[rows_log[pre], f + 1] * DT_S
                vxy[pre] = g.log_vxy[rows_log[pre], f + 1]
            _move(api, g, rows_log, xy, vxy)
        if f > T0_INDEX:
            rows_ego = g.ego_rows
            xy = g.cmd_xy[:, f]
            vxy = g.cmd_vxy[:, f]
            if reactive:
                prev = np.hypot(*g.cmd_vxy[:, f - 1].T) if f - 1 > T0_INDEX else np.hypot(*g.rec_vxy[rows_ego, f - 1].T)
                for r, s in zip(rows_ego.tolist(), prev.tolist(), strict=True):
                    api.vehicle.setPreviousSpeed(g.sumo_id[r], s)
            _move(api, g, rows_ego, xy, vxy)

        api.simulationStep()

        # --- read back -------------------------------------------------------------------------
        results = api.vehicle.getAllSubscriptionResults()
        for r in np.flatnonzero(g.present).tolist():
            res = results.get(g.sumo_id[r])
            if res is None:  # SUMO removed it (end of the road)
                del id_to_row[g.sumo_id[r]]
                g.present[r] = False
                continue
            px, py = res[tc.VAR_POSITION]
            g.rec_xy[r, f, 0] = px - g.x_off[r] - 0.5 * lengths[r]
            g.rec_xy[r, f, 1] = py - g.y_off[r]
            if g.released[r]:
                prev_y = g.rec_xy[r, f - 1, 1]
                vy = (g.rec_xy[r, f, 1] - prev_y) / DT_S if math.isfinite(prev_y) else 0.0
                g.rec_vxy[r, f] = (res[tc.VAR_SPEED], vy)
        g.rec_valid[:, f] = g.present & ~preroll
        logged = g.rec_valid[:, f] & want_log
        g.rec_vxy[logged, f] = g.log_vxy[logged, f]
        if f > T0_INDEX:
            g.rec_vxy[g.ego_rows, f] = g.cmd_vxy[:, f]
            g.ego_axy[:, f] = (g.cmd_vxy[:, f] - g.rec_vxy[g.ego_rows, f - 1]) / DT_S
        g.rec_xy[~g.rec_valid[:, f], f] = np.nan
        g.rec_vxy[~g.rec_valid[:, f], f] = np.nan
        simulated = g.rec_valid[:, f] & ~want_log
        if simulated.any():
            rows = np.flatnonzero(simulated)
            marks = batch.marking_y_m[g.scn[rows]]
            g.rec_lane[rows, f] = lane_ids_from_y(marks, batch.lane_ids[g.scn[rows]], g.rec_xy[rows, f, 1:2])[:, 0]
        g.rec_lane[~g.rec_valid[:, f], f] = 0
        if f > T0_INDEX:
            for col in api.simulation.getCollisions():
                a, b = id_to_row.get(col.collider), id_to_row.get(col.victim)
                if a is None or b is None or g.scn[a] != g.scn[b]:
                    continue
                if g.is_ego[a] or g.is_ego[b]:
                    other = b if g.is_ego[a] else a
                    contact[g.scn[a], g.nbr_slot[other], f - T0_INDEX - 1] = True
                else:
                    nbr_collisions[g.scn[a]] += 1

        # --- replanning --------------------------------------------------------------------------
        if f in replans:
            r_idx = replans.index(f)
            t0 = time.perf_counter()
            view, centre = replanning_batch(batch, g.states(), f, future)
            plan = plan_in_batches(planner, view)
            plan_s += time.perf_counter() - t0
            _check_plan(plan, g.k, n_future, planner)
            xy = np.asarray(plan.xy_m, dtype=np.float64) + centre[:, None, :]
            vxy = np.asarray(plan.vxy_mps, dtype=np.float64)
            plans_xy[:, r_idx] = xy
            goals_xy[:, r_idx] = np.asarray(plan.goals_xy_m, dtype=np.float64) + centre
            for key, val in plan.info.items():
                arr = np.asarray(val)
                if arr.ndim == 1 and arr.dtype.kind in "biuf":
                    info.setdefault(key, np.full((g.k, len(replans)), np.nan))[:, r_idx] = arr
            stop = min(f + replan_every, N_TOTAL - 1)
            n_use = stop - f
            use_xy, use_vxy = xy[:, :n_use], vxy[:, :n_use]
            bad = ~(np.isfinite(use_xy).all(axis=(1, 2)) & np.isfinite(use_vxy).all(axis=(1, 2)))
            with np.errstate(invalid="ignore"):
                bad |= ~_inside(use_xy, road_y, config).all(axis=1)
            if bad.any():
                nonfinite |= bad
                v0 = g.rec_vxy[g.ego_rows[bad], f]
                steps = np.arange(1, n_use + 1)[None, :, None] * DT_S
                use_xy[bad] = centre[bad, None, :] + v0[:, None, :] * steps
                use_vxy[bad] = v0[:, None, :]
            g.cmd_xy[:, f + 1 : stop + 1] = use_xy
            g.cmd_vxy[:, f + 1 : stop + 1] = use_vxy

    states = g.states()
    fut = slice(T0_INDEX + 1, N_TOTAL)
    elapsed = time.perf_counter() - t_start
    return ClosedLoopChunk(
        indices=np.arange(g.k),
        scenario_id=np.asarray(batch.scenario_id),
        planner=str(planner.name),
        mode=str(config.mode.value),
        replan_s=replan_every * DT_S,
        ego_xy_m=states.ego_xy_m[:, fut].copy(),
        ego_vxy_mps=states.ego_vxy_mps[:, fut].copy(),
        nbr_xy_m=states.nbr_xy_m[:, :, fut].copy(),
        nbr_vxy_mps=states.nbr_vxy_mps[:, :, fut].copy(),
        nbr_valid=states.nbr_valid[:, :, fut].copy(),
        nbr_lane_id=states.nbr_lane_id[:, :, fut].astype(np.int8),
        replan_step=np.asarray(replans, dtype=np.int64) - T0_INDEX,
        plan_xy_m=plans_xy,
        plan_goal_xy_m=goals_xy,
        plan_nonfinite=nonfinite,
        sumo_contact=contact,
        sumo_nbr_collisions=nbr_collisions,
        plan_s=np.full(g.k, plan_s / g.k),
        sim_s=np.full(g.k, (elapsed - plan_s) / g.k),
        cpu_s=np.full(g.k, (time.process_time() - cpu_start) / g.k),
        plan_info=info,
    )


def _move(api: Any, g: _Group, rows: np.ndarray, xy: np.ndarray, vxy: np.ndarray) -> None:
    xs, ys, angles = _front_and_angle(xy, vxy, g.length[rows], g.x_off[rows], g.y_off[rows])
    for r, x, y, a in zip(rows.tolist(), xs, ys, angles, strict=True):
        api.vehicle.moveToXY(g.sumo_id[r], "", -1, x, y, a, 2)


def _release(api: Any, g: _Group, f: int, config: ClosedLoopConfig) -> None:
    """Hand neighbours recorded at frame f - 1 and still unreleased over to SUMO's driver models."""
    rows = np.flatnonzero(~g.is_ego & g.present & ~g.released & g.rec_valid[:, f - 1])
    if rows.size == 0:
        return
    hist = slice(0, f)
    xy = g.rec_xy.reshape(g.k, g.per, N_TOTAL, 2)[:, :, hist]
    vx = g.rec_vxy.reshape(g.k, g.per, N_TOTAL, 2)[:, :, hist, 0]
    valid = g.rec_valid.reshape(g.k, g.per, N_TOTAL)[:, :, hist]
    desired, headway = estimate_driver_params(
        xy, vx, valid, g.length.reshape(g.k, g.per), g.width.reshape(g.k, g.per), config.driver
    )
    desired, headway = desired.reshape(-1), headway.reshape(-1)
    for r in rows.tolist():
        vid = g.sumo_id[r]
        api.vehicle.setMaxSpeed(vid, float(desired[r]))
        api.vehicle.setTau(vid, float(headway[r]))
        api.vehicle.setPreviousSpeed(vid, float(np.hypot(*g.rec_vxy[r, f - 1])))
        api.vehicle.setSpeedMode(vid, SPEED_MODE_ALL_CHECKS)
        api.vehicle.setLaneChangeMode(vid, LANE_CHANGE_MODE_DEFAULT)
        g.released[r] = True


def _inside(xy: np.ndarray, road_y: np.ndarray, config: ClosedLoopConfig) -> np.ndarray:
    """(K, S) whether planned positions (K, S, 2) lie in the simulated area: on the road's length and
    within ``OFF_ROAD_MARGIN_M`` of its edges (further out SUMO cannot place a vehicle sensibly)."""
    x_ok = (xy[..., 0] > -config.road_behind_m + 50.0) & (xy[..., 0] < config.road_ahead_m - 50.0)
    y_ok = (xy[..., 1] > road_y[:, :1] - OFF_ROAD_MARGIN_M) & (xy[..., 1] < road_y[:, 1:] + OFF_ROAD_MARGIN_M)
    return np.asarray(x_ok & y_ok)


def _check_plan(plan: PlanBatch, k: int, n_future: int, planner: Planner) -> None:
    if plan.xy_m.shape != (k, n_future, 2):
        raise ValueError(
            f"planner {planner.name!r} returned plans of shape {plan.xy_m.shape}, expected {(k, n_future, 2)}"
        )
