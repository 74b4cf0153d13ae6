"""The closed-loop simulation of one chunk in SUMO: K scenarios side by side (one road each), in lockstep.

Every 0.04 s frame ``simulate_group`` runs ``_Lockstep``'s five steps: who drives, bookkeeping (log-driven vehicles
are inserted one frame early: SUMO checks no collisions in an insertion step), the simulation step (``moveToXY``
keepRoute 2: exact positions), the contact check (boxes as in the metrics, contact only) and replanning."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from letspi.constants import DT_S, N_TOTAL, T0_INDEX
from letspi.planners.base import Planner
from letspi.scenario.types import ScenarioBatch
from letspi.simulation.config import ClosedLoopConfig, EvaluationMode
from letspi.simulation.drivers import estimate_driver_params
from letspi.simulation.handover import within_reach
from letspi.simulation.network import VTYPE_ID, SlotNetwork, layout_keys
from letspi.simulation.plans import PlanLog, follow_plans
from letspi.simulation.replan import (
    FuturePolicy,
    PeriodicReplanner,
    Replan,
    Replanner,
    SimulatedStates,
    lane_ids_from_y,
    plan_in_batches,
    replan_frames_of,
)
from letspi.simulation.result import ClosedLoopChunk
from letspi.simulation.session import SumoSession

__all__ = ["plan_in_batches", "replan_frames_of", "simulate_group"]

SPEED_MODE_ALL_CHECKS = 31
SPEED_MODE_SAFE_SPEED_ONLY = 25  # a commanded speed is bounded by the safe speed, not by accel/decel limits
LANE_CHANGE_MODE_NONE = 0
LANE_CHANGE_MODE_DEFAULT = 1621
MIN_HEADING_SPEED_MPS = 0.5


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
        self.released_at = np.full(v, -1, dtype=np.int64)  # frame from which SUMO drives it
        self.log_capped = np.zeros(v, dtype=bool)  # SUMO-driven, but not faster than its log (hybrid)
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


@dataclass(frozen=True)
class _Drive:
    """Who drives each of the V vehicles in one frame (all (V,) bool). log: placed on its log (everyone up to t = 0,
    then the neighbours not handed over); want_log: log-driven and recorded now; preroll: log-driven, recorded from
    the next frame (inserted early); plan: the ego following its plan (after t = 0)."""

    log: np.ndarray
    want_log: np.ndarray
    preroll: np.ndarray
    plan: np.ndarray


class _Lockstep:
    """One lockstep simulation of K scenarios in a SUMO network: the per-frame steps of ``simulate_group``."""

    def __init__(
        self, session: SumoSession, batch: ScenarioBatch, config: ClosedLoopConfig, run_tag: str,
        scripted_nbr: np.ndarray | None,
    ) -> None:  # fmt: skip
        widths = set(layout_keys(batch.marking_y_m))
        if len(widths) != 1:
            raise ValueError(f"simulate_group needs one lane layout, got {len(widths)}")
        net = session.open(widths.pop(), max(len(batch), config.scenarios_per_chunk()))
        self.api: Any = session.api
        self.tc = self.api.constants
        self.config = config
        self.mode = config.mode
        self.batch = batch
        self.g = g = _Group(batch, net, run_tag)
        scripted = np.zeros((g.k, g.n), dtype=bool) if scripted_nbr is None else np.asarray(scripted_nbr, dtype=bool)
        if scripted.shape != (g.k, g.n):
            raise ValueError(f"scripted_nbr must be (K, N) = {(g.k, g.n)}, got {scripted.shape}")
        self.scripted = np.concatenate([np.zeros((g.k, 1), dtype=bool), scripted], axis=1).reshape(-1)
        self.id_to_row: dict[str, int] = {}
        self.lengths = g.length.tolist()
        self.widths = g.width.tolist()
        self.road_y = np.stack([np.nanmin(batch.marking_y_m, axis=1), np.nanmax(batch.marking_y_m, axis=1)], axis=1)
        n_future = N_TOTAL - T0_INDEX - 1
        self.contact = np.zeros((g.k, g.n, n_future), dtype=bool)
        self.nbr_collisions = np.zeros(g.k, dtype=np.int64)
        self.nonfinite = np.zeros(g.k, dtype=bool)

    # --- 1. who drives ---------------------------------------------------------------------------
    def who_drives(self, f: int) -> _Drive:
        """Hand neighbours over to SUMO where the mode says so, then who is driven how in frame f."""
        g = self.g
        if f > T0_INDEX and self.mode.has_drivers:
            self.hand_over(f)
        log = np.ones_like(g.is_ego) if f <= T0_INDEX else ~g.is_ego & ~g.released
        want_log = log & g.log_valid[:, f]
        nxt = g.log_valid[:, f + 1] if f + 1 < N_TOTAL else np.zeros_like(want_log)
        preroll = log & ~want_log & nxt & ~g.present
        return _Drive(log=log, want_log=want_log, preroll=preroll, plan=g.is_ego & (f > T0_INDEX))

    def hand_over(self, f: int) -> None:
        """Hand replayed neighbours recorded at f - 1 to SUMO's drivers: all (reactive; a late entrant one frame
        after it appears) or those within the ego's reach, scripted actors excepted (hybrid)."""
        g = self.g
        rows = np.flatnonzero(~g.is_ego & g.present & ~g.released & g.rec_valid[:, f - 1])
        if self.mode is EvaluationMode.HYBRID:
            rows = rows[~self.scripted[rows]]
        if self.mode is EvaluationMode.HYBRID and rows.size:
            ego = g.ego_rows[g.scn[rows]]
            marks = self.batch.marking_y_m[g.scn[rows]]
            reach = within_reach(g.rec_xy[ego, f - 1], g.length[ego], g.width[ego], g.rec_xy[rows, f - 1][:, None],
                                 g.length[rows][:, None], marks, self.config.handover)[:, 0]
            rows = rows[reach]
        if rows.size:
            self._release(rows, f)

    def _release(self, rows: np.ndarray, f: int) -> None:
        """Driver parameters from the history up to f - 1; SUMO takes ``rows`` over where and as fast as they were."""
        g = self.g
        scenarios = np.unique(g.scn[rows])
        hist = slice(0, f)

        def per_scenario(a: np.ndarray) -> np.ndarray:
            return a.reshape(g.k, g.per, *a.shape[1:])[scenarios]

        desired, headway = estimate_driver_params(
            per_scenario(g.rec_xy)[:, :, hist], per_scenario(g.rec_vxy)[:, :, hist, 0],
            per_scenario(g.rec_valid)[:, :, hist], per_scenario(g.length), per_scenario(g.width), self.config.driver,
        )  # fmt: skip
        pos = np.searchsorted(scenarios, g.scn[rows]) * g.per + (g.nbr_slot[rows] + 1)
        desired, headway = desired.reshape(-1)[pos], headway.reshape(-1)[pos]
        capped = self.mode is EvaluationMode.HYBRID and self.config.handover.follow_log_speed
        for r, v0, tau in zip(rows.tolist(), desired.tolist(), headway.tolist(), strict=True):
            vid = g.sumo_id[r]
            self.api.vehicle.setMaxSpeed(vid, float(v0))
            self.api.vehicle.setTau(vid, float(tau))
            self.api.vehicle.setPreviousSpeed(vid, float(np.hypot(*g.rec_vxy[r, f - 1])))
            self.api.vehicle.setSpeedMode(vid, SPEED_MODE_SAFE_SPEED_ONLY if capped else SPEED_MODE_ALL_CHECKS)
            self.api.vehicle.setLaneChangeMode(vid, LANE_CHANGE_MODE_DEFAULT)
        g.released[rows] = True
        g.released_at[rows] = f
        g.log_capped[rows] = capped

    def _cap_to_log(self, f: int) -> None:
        """Log-capped vehicles get their recorded speed of frame f (SUMO's safe speed may lower it); after their
        log ends, SUMO's driver model alone."""
        g = self.g
        rows = np.flatnonzero(g.log_capped & g.present)
        if rows.size == 0:
            return
        ended = ~g.log_valid[rows, f]
        speed = np.hypot(*g.log_vxy[rows, f].T)
        for r, done, v in zip(rows.tolist(), ended.tolist(), speed.tolist(), strict=True):
            if done:
                self.api.vehicle.setSpeed(g.sumo_id[r], -1.0)
                self.api.vehicle.setSpeedMode(g.sumo_id[r], SPEED_MODE_ALL_CHECKS)
            else:
                self.api.vehicle.setSpeed(g.sumo_id[r], v)
        g.log_capped[rows[ended]] = False

    # --- 2. vehicle bookkeeping --------------------------------------------------------------------
    def bookkeeping(self, drive: _Drive) -> None:
        """Remove log-driven vehicles that left the log; insert those (about to be) in it and the ego."""
        g, api = self.g, self.api
        to_remove = np.flatnonzero(g.present & drive.log & ~drive.want_log & ~drive.preroll)
        to_add = np.flatnonzero((drive.want_log | drive.preroll | drive.plan) & ~g.present)
        for r in to_remove.tolist():
            api.vehicle.unsubscribe(g.sumo_id[r])  # libsumo fails the next step on a removed subscriber
            api.vehicle.remove(g.sumo_id[r])
            del self.id_to_row[g.sumo_id[r]]
            g.present[r] = False
        sub_vars = (self.tc.VAR_POSITION, self.tc.VAR_SPEED)
        for r in to_add.tolist():
            vid = f"{g.prefix}.{r}.{int(g.generation[r])}"
            g.generation[r] += 1
            api.vehicle.add(vid, g.route[r], VTYPE_ID, depart="now")
            api.vehicle.setLength(vid, self.lengths[r])
            api.vehicle.setWidth(vid, self.widths[r])
            api.vehicle.setSpeedMode(vid, 0)
            api.vehicle.setLaneChangeMode(vid, LANE_CHANGE_MODE_NONE)
            api.vehicle.subscribe(vid, sub_vars)
            g.sumo_id[r] = vid
            self.id_to_row[vid] = r
            g.present[r] = True

    # --- 3. simulation step --------------------------------------------------------------------------
    def simulation_step(self, f: int, drive: _Drive) -> None:
        """Place the log-driven vehicles and the ego, advance SUMO one step, read every state back."""
        self._command(f, drive)
        self.api.simulationStep()
        self._read_back(f, drive)

    def _command(self, f: int, drive: _Drive) -> None:
        g = self.g
        self._cap_to_log(f)
        rows_log = np.flatnonzero(drive.want_log | drive.preroll)
        if rows_log.size:
            xy = g.log_xy[rows_log, f].copy()
            vxy = g.log_vxy[rows_log, f].copy()
            pre = drive.preroll[rows_log]
            if pre.any():
                xy[pre] = g.log_xy[rows_log[pre], f + 1] - g.log_vxy[rows_log[pre], f + 1] * DT_S
                vxy[pre] = g.log_vxy[rows_log[pre], f + 1]
            self._move(rows_log, xy, vxy)
        if f > T0_INDEX:
            rows_ego = g.ego_rows
            if self.mode.has_drivers:  # SUMO's followers brake for the speed the ego had, not 0
                prev = np.hypot(*g.cmd_vxy[:, f - 1].T) if f - 1 > T0_INDEX else np.hypot(*g.rec_vxy[rows_ego, f - 1].T)
                for r, s in zip(rows_ego.tolist(), prev.tolist(), strict=True):
                    self.api.vehicle.setPreviousSpeed(g.sumo_id[r], s)
            self._move(rows_ego, g.cmd_xy[:, f], g.cmd_vxy[:, f])

    def _move(self, rows: np.ndarray, xy: np.ndarray, vxy: np.ndarray) -> None:
        g = self.g
        xs, ys, angles = _front_and_angle(xy, vxy, g.length[rows], g.x_off[rows], g.y_off[rows])
        move, ids = self.api.vehicle.moveToXY, g.sumo_id
        for r, x, y, a in zip(rows.tolist(), xs, ys, angles, strict=True):
            move(ids[r], "", -1, x, y, a, 2)

    def _read_back(self, f: int, drive: _Drive) -> None:
        g, tc = self.g, self.tc
        results = self.api.vehicle.getAllSubscriptionResults()
        rows = np.flatnonzero(g.present)
        found = [results.get(g.sumo_id[r]) for r in rows.tolist()]
        if None in found:  # SUMO removed them (end of the road)
            kept = np.array([res is not None for res in found], dtype=bool)
            for r in rows[~kept].tolist():
                del self.id_to_row[g.sumo_id[r]]
            g.present[rows[~kept]] = False
            rows = rows[kept]
            found = [res for res in found if res is not None]
        if rows.size:
            pos = np.array([res[tc.VAR_POSITION] for res in found], dtype=np.float64).reshape(-1, 2)
            g.rec_xy[rows, f, 0] = pos[:, 0] - g.x_off[rows] - 0.5 * g.length[rows]
            g.rec_xy[rows, f, 1] = pos[:, 1] - g.y_off[rows]
            moved = g.released[rows]
            if moved.any():  # SUMO drives them: its speed along x, the lateral speed from the positions
                rel = rows[moved]
                prev_y = g.rec_xy[rel, f - 1, 1]
                with np.errstate(invalid="ignore"):
                    vy = np.where(np.isfinite(prev_y), (g.rec_xy[rel, f, 1] - prev_y) / DT_S, 0.0)
                g.rec_vxy[rel, f, 0] = [found[i][tc.VAR_SPEED] for i in np.flatnonzero(moved).tolist()]
                g.rec_vxy[rel, f, 1] = vy
        g.rec_valid[:, f] = g.present & ~drive.preroll
        logged = g.rec_valid[:, f] & drive.want_log
        g.rec_vxy[logged, f] = g.log_vxy[logged, f]
        if f > T0_INDEX:
            g.rec_vxy[g.ego_rows, f] = g.cmd_vxy[:, f]
            g.ego_axy[:, f] = (g.cmd_vxy[:, f] - g.rec_vxy[g.ego_rows, f - 1]) / DT_S
        g.rec_xy[~g.rec_valid[:, f], f] = np.nan
        g.rec_vxy[~g.rec_valid[:, f], f] = np.nan
        simulated = g.rec_valid[:, f] & ~drive.want_log
        if simulated.any():
            rows = np.flatnonzero(simulated)
            marks = self.batch.marking_y_m[g.scn[rows]]
            ids = lane_ids_from_y(marks, self.batch.lane_ids[g.scn[rows]], g.rec_xy[rows, f, 1:2])
            g.rec_lane[rows, f] = ids[:, 0]
        g.rec_lane[~g.rec_valid[:, f], f] = 0

    # --- 4. contact check ----------------------------------------------------------------------------
    def contact_check(self, f: int) -> None:
        """SUMO's collisions of this step: ego contacts per neighbour slot, neighbour pairs counted."""
        if f <= T0_INDEX:
            return
        g = self.g
        for col in self.api.simulation.getCollisions():
            a, b = self.id_to_row.get(col.collider), self.id_to_row.get(col.victim)
            if a is None or b is None or g.scn[a] != g.scn[b]:
                continue
            if g.is_ego[a] or g.is_ego[b]:
                other = b if g.is_ego[a] else a
                self.contact[g.scn[a], g.nbr_slot[other], f - T0_INDEX - 1] = True
            else:
                self.nbr_collisions[g.scn[a]] += 1

    # --- 5. following a plan ----------------------------------------------------------------------
    def follow(self, f: int, replan: Replan) -> None:
        """The ego commands of the scenarios that replanned at frame f (``letspi.simulation.plans.follow_plans``)."""
        g = self.g
        follow_plans(replan, f, g.rec_xy[g.ego_rows, f], g.rec_vxy[g.ego_rows, f], self.road_y, self.config,
                     g.cmd_xy, g.cmd_vxy, self.nonfinite)


def simulate_group(
    session: SumoSession,
    planner: Planner,
    batch: ScenarioBatch,
    config: ClosedLoopConfig,
    *,
    future: FuturePolicy,
    run_tag: str = "g",
    scripted_nbr: np.ndarray | None = None,
    replanner: Replanner | None = None,
) -> ClosedLoopChunk:
    """Simulate K scenarios of one lane layout together (chunk ``indices`` 0..K-1). scripted_nbr: (K, N) bool, slots
    that replay their log throughout in ``closed-loop-hybrid``; replanner: default ``PeriodicReplanner``."""
    t_start = time.perf_counter()
    cpu_start = time.process_time()
    sim = _Lockstep(session, batch, config, run_tag, scripted_nbr)
    replanner = replanner or PeriodicReplanner(planner, batch, config.replan_frames, future)
    plans = PlanLog(sim.g.k, replanner.frames)
    for f in range(N_TOTAL):
        drive = sim.who_drives(f)
        sim.bookkeeping(drive)
        sim.simulation_step(f, drive)
        sim.contact_check(f)
        replan = replanner.plans(f, sim.g.states())
        if replan is not None:
            plans.add(f, replan)
            sim.follow(f, replan)
    return _chunk(sim, plans, planner, config.replan_frames, time.perf_counter() - t_start,
                  time.process_time() - cpu_start)


def _chunk(sim: _Lockstep, plans: PlanLog, planner: Planner, replan_every: int, wall_s: float,
           cpu_s: float) -> ClosedLoopChunk:
    g = sim.g
    states = g.states()
    fut = slice(T0_INDEX + 1, N_TOTAL)
    released_at = g.released_at.reshape(g.k, g.per)[:, 1:]
    return ClosedLoopChunk(
        indices=np.arange(g.k), scenario_id=np.asarray(sim.batch.scenario_id), planner=str(planner.name),
        mode=str(sim.mode.value), replan_s=replan_every * DT_S,
        ego_xy_m=states.ego_xy_m[:, fut].copy(), ego_vxy_mps=states.ego_vxy_mps[:, fut].copy(),
        nbr_xy_m=states.nbr_xy_m[:, :, fut].copy(), nbr_vxy_mps=states.nbr_vxy_mps[:, :, fut].copy(),
        nbr_valid=states.nbr_valid[:, :, fut].copy(), nbr_lane_id=states.nbr_lane_id[:, :, fut].astype(np.int8),
        nbr_handover_step=np.where(released_at >= 0, released_at - T0_INDEX - 1, -1),
        replan_step=np.asarray(plans.frames, dtype=np.int64) - T0_INDEX, plan_xy_m=plans.xy, plan_goal_xy_m=plans.goals,
        plan_nonfinite=sim.nonfinite, sumo_contact=sim.contact, sumo_nbr_collisions=sim.nbr_collisions,
        plan_s=np.full(g.k, plans.plan_s / g.k), sim_s=np.full(g.k, (wall_s - plans.plan_s) / g.k),
        cpu_s=np.full(g.k, cpu_s / g.k), plan_info=plans.info)


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
