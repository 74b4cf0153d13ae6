"""Scripted critical events (``hard_brake``, ``cut_in``, ``truck_pullout``; knobs in ``EventConfig``) and lane-change
perception (the closing follower of every lane change into the window is held, ``reactions``), through libsumo.

Timing: ``on_step(t)`` gets SUMO's current time t, that of the next step (the vehicles are in the state of step
t - 0.04 s); commands act in step t, which is recorded as the event time. Events start only on lane-centred,
steady vehicles in no other event, in the upstream part of the window, drawn with the injector's own generator."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from letspi.trafficgen.config import EventConfig
from letspi.trafficgen.reactions import LC_MODE_DEFAULT, LC_MODE_FORCED, SPEED_MODE_DEFAULT, STEP_S, Hold, Reactions

_SPEED_MODE_NO_DECEL_BOUND = 27  # 31 minus bit 2 (regard maximum deceleration)
_LANE_CENTRED_M = 0.2  # a vehicle further from its lane centre is (still) changing lanes
_RETRY_S = 0.5  # no candidate now: look again after this
_GIVE_UP_S = 20.0
_ZONE_M = (10.0, 260.0)  # event start zone: distance of the actor's front past the window entry [m]
_MAX_INITIAL_DRAC_MPS2 = 5.0  # forced lane changes never need more braking than this at once
_MIN_GAP_AHEAD_M = 20.0  # room in front of a lane changer on its target lane
_STEADY_ACCEL_MPS2 = -1.0  # vehicles braking harder than this are not drawn into a new event
_SCAN_S = 0.2  # lane-change perception: how often lane changes are looked for
_SCAN_MARGIN_M = 250.0  # vehicles this far around the window are read (leaders, followers)
_PERCEPTION_RANGE_M = 100.0  # followers further behind a lane changer are not affected
_POI = "letspi_window"
LANE_CHANGE_S = 4.0  # SUMO's --lanechange.duration (see simulate.py)

KINDS = ("hard_brake", "cut_in", "truck_pullout")


@dataclass(frozen=True)
class VehicleInfo:
    """Static per-vehicle data: ``length_m``, ``east`` (HighD direction 2), ``truck``, ``reaction_s`` [s]."""

    length_m: float
    east: bool
    truck: bool
    reaction_s: float


@dataclass(frozen=True)
class Window:
    """The recorded window in SUMO coordinates: x range [m] and the main lane centres' y [m] (index 0 = rightmost)."""

    x0_m: float
    x1_m: float
    east_centres_y_m: np.ndarray
    west_centres_y_m: np.ndarray


@dataclass(frozen=True)
class EventRecord:
    """One injected event in simulation terms (converted to HighD ids and frames when written, as ``NN_events.csv``).
    ``time_s``: first time it acts [s]; ``kind`` (``failed``: a lane change SUMO did not carry out, never written);
    ``actor``, ``other``: SUMO ids; ``lane``, ``target_lane``: main-lane indices (0 = rightmost); ``target_speed_mps``
    and ``decel_mps2`` are NaN for lane changes; ``reaction_s`` is 0 when followers are not held; ``held_s``: how long
    the follower kept its speed; ``other_decel_mps2``: NaN when SUMO's car following takes over at once."""

    time_s: float
    kind: str
    actor: str
    other: str
    lane: int
    target_lane: int
    speed_mps: float
    target_speed_mps: float
    decel_mps2: float
    duration_s: float
    gap_m: float
    reaction_s: float
    held_s: float = 0.0
    other_decel_mps2: float = float("nan")


@dataclass
class _Snapshot:
    """Vehicles near the window at the last step; arrays of shape (N,) in ``ids`` order."""

    ids: list[str]
    s: np.ndarray  # progress of the front bumper along the travel direction [m]
    speed: np.ndarray
    accel: np.ndarray
    length: np.ndarray
    east: np.ndarray
    lane: np.ndarray  # nearest main lane index (-1: not on a main lane)
    offset: np.ndarray  # signed lateral distance from that lane's centre, towards higher indices [m]
    centred: np.ndarray
    truck: np.ndarray
    in_zone: np.ndarray
    in_window: np.ndarray


@dataclass
class _Pending:
    time_s: float
    action: str  # "hold_speed", "release_leader", "restore_lc"
    vehicle: str
    value: float = 0.0


@dataclass
class EventInjector:
    """The scripted events and lane-change perception of one simulation: after every ``simulationStep`` whose end
    time ``t`` is >= ``next_wakeup()``, call ``on_step(t)``."""

    sim: Any  # the libsumo module
    config: EventConfig
    rng: np.random.Generator
    window: Window
    vehicles: dict[str, VehicleInfo]
    start_s: float
    end_s: float
    lane_change_perception: bool = True
    records: list[EventRecord] = field(default_factory=list)
    perceived_lane_changes: int = 0
    _due: dict[str, float] = field(default_factory=dict)
    # when each kind's pending event was meant to start: the next is drawn from there, keeping the rate
    _intended: dict[str, float] = field(default_factory=dict)
    _pending: list[_Pending] = field(default_factory=list)
    _busy_until: dict[str, float] = field(default_factory=dict)
    _last_lane: dict[str, int] = field(default_factory=dict)
    _next_scan_s: float = float("inf")
    _reactions: Reactions | None = None

    def __post_init__(self) -> None:
        self._reactions = Reactions(self.sim, self.config.release_decel_mps2, self.config.release_gap_m,
                                    self.config.follower_jerk_mps3, [], self._gap_to)
        for kind in KINDS:
            self._schedule(kind, self.start_s)
        w = self.window
        centres = np.concatenate([w.east_centres_y_m, w.west_centres_y_m])
        yc = 0.5 * (float(centres.min()) + float(centres.max()))
        xc = 0.5 * (w.x0_m + w.x1_m)
        radius = 0.5 * (w.x1_m - w.x0_m) + _SCAN_MARGIN_M
        c = self.sim.constants
        self.sim.poi.add(_POI, xc, yc, (0, 0, 0, 0))
        self.sim.poi.subscribeContext(_POI, c.CMD_GET_VEHICLE_VARIABLE, radius,
                                      [c.VAR_POSITION, c.VAR_SPEED, c.VAR_ACCELERATION])
        if self.lane_change_perception:
            self._next_scan_s = self.start_s

    def stats(self) -> dict[str, int]:
        """Counters for the generation report."""
        return {"perceived_lane_changes": self.perceived_lane_changes,
                "failed_lane_changes": sum(r.kind == "failed" for r in self.records)}

    @property
    def reactions(self) -> Reactions:
        assert self._reactions is not None
        return self._reactions

    # ---------------------------------------------------------------- scheduling
    def _schedule(self, kind: str, after_s: float) -> None:
        rate = float(getattr(self.config, f"{kind}_per_min")) / 60.0
        t = after_s + float(self.rng.exponential(1.0 / rate)) if rate > 0.0 else float("inf")
        if t < self.end_s:
            self._due[kind] = t
        else:
            self._due.pop(kind, None)

    def next_wakeup(self) -> float:
        """Earliest simulation time at which the injector must run (inf if never again)."""
        if self.reactions.holds:
            return 0.0  # held followers are advanced every step
        times = [*self._due.values(), *(p.time_s for p in self._pending), self._next_scan_s]
        return min(times)

    # ---------------------------------------------------------------- per step
    def on_step(self, t: float) -> None:
        """Run what is due at simulation time ``t`` (the end time of the step just done)."""
        self.reactions.step(t, self._alive)
        for p in [p for p in self._pending if p.time_s <= t + 1e-9]:
            self._pending.remove(p)
            self._run_pending(p)
        due = sorted((time, kind) for kind, time in self._due.items() if time <= t + 1e-9)
        scan = t + 1e-9 >= self._next_scan_s
        if not due and not scan:
            return
        snap = self._snapshot()
        for first_due, kind in due:
            if snap is not None and self._start(kind, t, snap):
                self._schedule(kind, self._intended.pop(kind, first_due))
            elif t - self._intended.setdefault(kind, first_due) > _GIVE_UP_S:
                self._schedule(kind, self._intended.pop(kind))
            else:
                self._due[kind] = t + _RETRY_S
        if scan:
            if snap is not None:
                self._perceive_lane_changes(t, snap)
            self._next_scan_s = t + _SCAN_S if t + _SCAN_S < self.end_s else float("inf")

    def _alive(self, vid: str) -> bool:
        try:
            self.sim.vehicle.getSpeed(vid)
        except Exception:  # libsumo raises TraCIException for vehicles that left
            return False
        return True

    def _run_pending(self, p: _Pending) -> None:
        if not self._alive(p.vehicle):
            return
        v = self.sim.vehicle
        if p.action == "hold_speed":
            v.setSpeed(p.vehicle, p.value)
        elif p.action == "release_leader":
            v.setSpeed(p.vehicle, -1.0)
            v.setSpeedMode(p.vehicle, SPEED_MODE_DEFAULT)
        elif p.action == "restore_lc":
            v.setLaneChangeMode(p.vehicle, LC_MODE_DEFAULT)
            self._verify_lane_change(p)

    def _verify_lane_change(self, p: _Pending) -> None:
        k = int(p.value)
        rec = self.records[k]
        _, y = self.sim.vehicle.getPosition(p.vehicle)
        centres = self.window.east_centres_y_m if self.vehicles[p.vehicle].east else self.window.west_centres_y_m
        if abs(y - centres[rec.target_lane]) > _LANE_CENTRED_M:
            self.records[k] = dataclasses.replace(rec, kind="failed")

    def _gap_to(self, follower: str, leader: str) -> float | None:
        """Bumper gap [m] from ``follower``'s front to ``leader``'s rear along the road (None if not ahead)."""
        f, a = self.vehicles[follower], self.vehicles[leader]
        xf, _ = self.sim.vehicle.getPosition(follower)
        xl, _ = self.sim.vehicle.getPosition(leader)
        ahead = (xl - xf) if f.east else (xf - xl)
        gap = ahead - a.length_m
        return gap if ahead > 0.0 else None

    def _set_held(self, k: int) -> Any:
        def update(held_s: float) -> None:
            self.records[k] = dataclasses.replace(self.records[k], held_s=held_s)
        return update

    # ---------------------------------------------------------------- state
    def _snapshot(self) -> _Snapshot | None:
        c = self.sim.constants
        results = self.sim.poi.getContextSubscriptionResults(_POI)
        ids = sorted(v for v in results if v in self.vehicles)
        if not ids:
            return None
        pos = np.array([results[i][c.VAR_POSITION] for i in ids], dtype=np.float64)
        x, y = pos[:, 0], pos[:, 1]
        info = [self.vehicles[i] for i in ids]
        east = np.array([i.east for i in info])
        length = np.array([i.length_m for i in info])
        w = self.window
        centres = np.where(east[:, None], w.east_centres_y_m[None, :], w.west_centres_y_m[None, :])
        signed = y[:, None] - centres
        lane = np.argmin(np.abs(signed), axis=1)
        offset = signed[np.arange(len(ids)), lane]
        # Towards higher lane indices (to the left of travel) is +y eastbound, -y westbound.
        offset = np.where(east, offset, -offset)
        lane = np.where(np.abs(offset) > 1.9, -1, lane)  # on a ramp / auxiliary lane
        s = np.where(east, x, -x)
        entry = np.where(east, w.x0_m, -w.x1_m)  # s of the window entry in the travel direction
        past_entry = s - entry
        window_m = w.x1_m - w.x0_m
        return _Snapshot(
            ids=ids, s=s, speed=np.array([results[i][c.VAR_SPEED] for i in ids], dtype=np.float64),
            accel=np.array([results[i][c.VAR_ACCELERATION] for i in ids], dtype=np.float64),
            length=length, east=east, lane=lane, offset=offset, centred=np.abs(offset) < _LANE_CENTRED_M,
            truck=np.array([i.truck for i in info]),
            in_zone=(past_entry - length >= _ZONE_M[0]) & (past_entry <= _ZONE_M[1]) & (lane >= 0),
            in_window=(past_entry - length >= 0.0) & (past_entry <= window_m) & (lane >= 0))  # whole box

    def _free(self, snap: _Snapshot, row: int, t: float, *, steady: bool = True) -> bool:
        """Not involved in another event, not held and (``steady``) not braking."""
        vid = snap.ids[row]
        return (self._busy_until.get(vid, -1.0) < t and vid not in self.reactions
                and (not steady or snap.accel[row] > _STEADY_ACCEL_MPS2))

    @staticmethod
    def _lane_neighbours(snap: _Snapshot, i: int, lane: int) -> tuple[int, int, bool]:
        """In ``lane`` of vehicle i's carriageway: (row entirely behind i, row entirely ahead, someone overlapping i
        along the road); rows are -1 when there is none."""
        same = (snap.east == snap.east[i]) & (snap.lane == lane) & (np.arange(len(snap.ids)) != i)
        rows = np.flatnonzero(same)
        if len(rows) == 0:
            return -1, -1, False
        front = snap.s[rows]
        rear = front - snap.length[rows]
        i_front, i_rear = snap.s[i], snap.s[i] - snap.length[i]
        behind = rows[front <= i_rear]
        ahead = rows[rear >= i_front]
        alongside = bool(np.any((front > i_rear) & (rear < i_front)))
        b = int(behind[np.argmax(snap.s[behind])]) if len(behind) else -1
        a = int(ahead[np.argmin(snap.s[ahead])]) if len(ahead) else -1
        return b, a, alongside

    # ---------------------------------------------------------------- lane-change perception
    def _perceive_lane_changes(self, t: float, snap: _Snapshot) -> None:
        """Hold the closing follower on the target lane of every lane change that just began."""
        v_lat = float(np.mean(np.abs(np.diff(self.window.east_centres_y_m)))) / LANE_CHANGE_S
        for i, vid in enumerate(snap.ids):
            lane = int(snap.lane[i])
            if snap.centred[i]:
                self._last_lane[vid] = lane
                continue
            origin = self._last_lane.pop(vid, None)  # popped: each lane change is seen once
            if origin is None or lane < 0 or not snap.in_window[i]:
                continue
            target = origin + (1 if snap.offset[i] > 0 else -1) if lane == origin else lane
            if target == origin or not 0 <= target < len(self.window.east_centres_y_m):
                continue
            f, _, _ = self._lane_neighbours(snap, i, target)
            # SUMO's follower may already brake for the changer: that is what is undone here.
            if f < 0 or not snap.centred[f] or not self._free(snap, f, t, steady=False):
                continue
            gap = snap.s[i] - snap.length[i] - snap.s[f]
            if snap.speed[f] - snap.speed[i] <= 0.5 or not 0.0 < gap <= _PERCEPTION_RANGE_M:
                continue
            # Lateral progress so far tells when the change began; the centre crosses halfway.
            crossed_from = abs(float(snap.offset[i])) if lane == origin else 0.0
            started = t - crossed_from / v_lat if lane == origin else t - 0.5 * LANE_CHANGE_S
            react_at = max(t, started + 0.5 * LANE_CHANGE_S) + self.vehicles[snap.ids[f]].reaction_s
            self.reactions.start(Hold(snap.ids[f], vid, t, react_at))
            self.perceived_lane_changes += 1

    # ---------------------------------------------------------------- events
    def _start(self, kind: str, t: float, snap: _Snapshot) -> bool:
        if kind == "hard_brake":
            return self._start_hard_brake(t, snap)
        return self._start_lane_change(kind, t, snap)

    def _start_hard_brake(self, t: float, snap: _Snapshot) -> bool:
        cfg = self.config
        # The braking is drawn first; only a leader fast enough to brake that long at that rate
        # without going below the minimum speed is chosen.
        decel = float(self.rng.uniform(*cfg.hard_brake_decel_mps2))
        duration = round(float(self.rng.uniform(*cfg.hard_brake_duration_s)) / STEP_S) * STEP_S  # whole steps
        hold = float(self.rng.uniform(*cfg.hard_brake_hold_s))
        ratio = float(self.rng.uniform(*cfg.follower_brake_ratio))
        candidates: list[tuple[int, int, float]] = []
        for row in np.flatnonzero(snap.in_zone & snap.centred):
            i = int(row)
            if snap.speed[i] - decel * duration < cfg.hard_brake_min_speed_mps or not self._free(snap, i, t):
                continue
            f, _, _ = self._lane_neighbours(snap, i, int(snap.lane[i]))
            if f < 0 or not snap.centred[f] or not self._free(snap, f, t) or not snap.in_window[f]:
                continue
            gap = snap.s[i] - snap.length[i] - snap.s[f]
            if snap.speed[f] <= 0 or gap / snap.speed[f] > cfg.hard_brake_max_headway_s:
                continue
            candidates.append((i, f, float(gap)))
        if not candidates or duration < STEP_S:
            return False
        i, f, gap = candidates[int(self.rng.integers(len(candidates)))]
        actor, follower = snap.ids[i], snap.ids[f]
        v0 = float(snap.speed[i])
        target = v0 - decel * duration
        veh = self.sim.vehicle
        veh.setSpeedMode(actor, _SPEED_MODE_NO_DECEL_BOUND)
        veh.slowDown(actor, target, duration)
        t0 = t
        # slowDown lowers the speed over the steps t0 .. t0 + duration - dt; then keep it.
        self._pending.append(_Pending(t0 + duration - 1e-6, "hold_speed", actor, target))
        self._pending.append(_Pending(t0 + duration + hold, "release_leader", actor))
        reaction = self.vehicles[follower].reaction_s if cfg.follower_reaction else 0.0
        if cfg.follower_reaction:
            self.reactions.start(Hold(follower, actor, t0, t0 + reaction, brake_decel_mps2=ratio * decel,
                                      leader_target_mps=target, leader_decel_mps2=decel,
                                      leader_brake_end_s=t0 + duration, on_release=self._set_held(len(self.records))))
        self._busy_until[actor] = self._busy_until[follower] = t0 + duration + hold + 2.0
        lane = int(snap.lane[i])
        self.records.append(EventRecord(round(t0, 2), "hard_brake", actor, follower, lane, lane, v0, target,
                                        decel, duration, gap, reaction,
                                        other_decel_mps2=ratio * decel if cfg.follower_reaction else float("nan")))
        return True

    def _start_lane_change(self, kind: str, t: float, snap: _Snapshot) -> bool:
        cfg = self.config
        truck = kind == "truck_pullout"
        gap_range = cfg.truck_pullout_gap_m if truck else cfg.cut_in_gap_m
        closing_range = cfg.truck_pullout_closing_mps if truck else cfg.cut_in_closing_mps
        ttc_range = cfg.truck_pullout_ttc_s if truck else cfg.cut_in_ttc_s
        n_lanes = len(self.window.east_centres_y_m)
        candidates: list[tuple[int, int, int, float]] = []
        actors = snap.in_zone & snap.centred & (snap.truck if truck else ~snap.truck)
        if truck:
            actors &= snap.lane == 0
        for row in np.flatnonzero(actors):
            i = int(row)
            if not self._free(snap, i, t):
                continue
            for j in ([1] if truck else [int(snap.lane[i]) + d for d in (1, -1)]):
                if not 0 <= j < n_lanes:
                    continue
                f, a, alongside = self._lane_neighbours(snap, i, j)
                if alongside or f < 0 or not snap.centred[f] or not self._free(snap, f, t) or not snap.in_window[f]:
                    continue
                gap = snap.s[i] - snap.length[i] - snap.s[f]
                closing = snap.speed[f] - snap.speed[i]
                if not (gap_range[0] <= gap <= gap_range[1] and closing_range[0] <= closing <= closing_range[1]):
                    continue
                # The follower keeps its speed until the changer's centre crosses (half the lane
                # change): enough gap must be left then, or the cut-in is not a cut-in.
                gap_at_cross = gap - closing * 0.5 * LANE_CHANGE_S
                if gap_at_cross < cfg.release_gap_m or closing**2 / (2.0 * gap_at_cross) > _MAX_INITIAL_DRAC_MPS2:
                    continue
                if not ttc_range[0] <= gap_at_cross / closing <= ttc_range[1]:
                    continue
                if a >= 0:
                    room = snap.s[a] - snap.length[a] - snap.s[i]
                    if room < _MIN_GAP_AHEAD_M or snap.speed[a] < snap.speed[i] - 2.0:
                        continue
                candidates.append((i, j, f, float(gap)))
        if not candidates:
            return False
        i, j, f, gap = candidates[int(self.rng.integers(len(candidates)))]
        actor, follower = snap.ids[i], snap.ids[f]
        veh = self.sim.vehicle
        veh.setLaneChangeMode(actor, LC_MODE_FORCED)
        # Main-lane indices count from the rightmost main lane; SUMO's from the edge's rightmost
        # lane, which is the auxiliary lane where the layout has one.
        offset = int(veh.getLaneIndex(actor)) - int(snap.lane[i])
        veh.changeLane(actor, j + offset, LANE_CHANGE_S + 1.0)
        t0 = t
        self._pending.append(_Pending(t0 + LANE_CHANGE_S + 1.0, "restore_lc", actor, len(self.records)))
        reaction = self.vehicles[follower].reaction_s if cfg.follower_reaction else 0.0
        if cfg.follower_reaction:
            # The follower perceives the cut-in when the changer's centre crosses into its lane.
            self.reactions.start(Hold(follower, actor, t0, t0 + 0.5 * LANE_CHANGE_S + reaction,
                                      on_release=self._set_held(len(self.records))))
        self._busy_until[actor] = self._busy_until[follower] = t0 + LANE_CHANGE_S + 3.0
        self._last_lane.pop(actor, None)  # not a natural lane change for the perception scan
        self.records.append(EventRecord(round(t0, 2), kind, actor, follower, int(snap.lane[i]), j,
                                        float(snap.speed[i]), float("nan"), float("nan"), LANE_CHANGE_S,
                                        gap, reaction))
        return True
