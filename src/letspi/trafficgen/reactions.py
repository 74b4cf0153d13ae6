"""Driver reaction for SUMO followers (``Reactions``, through libsumo): **hold** the speed (speed mode 30, no own
lane changes) until perception + reaction, optionally **brake** on a jerk-limited ramp until no longer closing in,
then **release** to SUMO; at once when avoiding contact would need more than ``release_decel_mps2``
(``required_decel``) or the gap falls below ``release_gap_m``."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

STEP_S = 0.04
SPEED_MODE_DEFAULT = 31
SPEED_MODE_HOLD = 30  # 31 minus bit 0 (regard safe speed): keep the speed although the leader brakes
SPEED_MODE_BRAKE = 26  # ... and minus bit 2: brake harder than the type's comfortable deceleration
LC_MODE_DEFAULT = 1621
LC_MODE_FORCED = 256  # no autonomous changes; TraCI requests avoid immediate collisions only
_MAX_BRAKING_S = 8.0  # a scripted braking phase never lasts longer
_A_GRID = np.arange(0.25, 12.25, 0.25)[:, None]  # candidate decelerations [m/s²], (A, 1)
_T_GRID = np.arange(1, 301) * STEP_S  # 12 s horizon, (T,)


def required_decel(gap_m: float, v_f_mps: float, v_l_mps: float, d_l_mps2: float, v_l_end_mps: float,
                   margin_m: float = 1.0) -> float:
    """Smallest constant deceleration [m/s²] (0.25 steps; 0: none needed, 12.25: 12 is not enough) keeping a follower
    braking from ``v_f_mps`` to the leader's final speed ``margin_m`` behind a leader braking at ``d_l_mps2`` from
    ``v_l_mps`` to ``v_l_end_mps`` (12 s horizon)."""
    t = _T_GRID
    if d_l_mps2 > 0.0:
        t_b = max(0.0, (v_l_mps - v_l_end_mps) / d_l_mps2)
        tb = np.minimum(t, t_b)
        x_l = v_l_mps * tb - 0.5 * d_l_mps2 * tb**2 + v_l_end_mps * (t - tb)
    else:
        v_l_end_mps = v_l_mps
        x_l = v_l_mps * t
    if np.min(gap_m + x_l - v_f_mps * t) >= margin_m:
        return 0.0
    v_goal = min(v_f_mps, v_l_end_mps)
    t_f = np.minimum(t[None, :], (v_f_mps - v_goal) / _A_GRID)  # (A, T)
    x_f = v_f_mps * t_f - 0.5 * _A_GRID * t_f**2 + v_goal * (t[None, :] - t_f)
    ok = np.min(gap_m + x_l[None, :] - x_f, axis=1) >= margin_m  # (A,)
    return float(_A_GRID[np.argmax(ok), 0]) if ok.any() else 12.25


@dataclass
class Hold:
    """One follower held from ``start_s`` until ``react_at_s`` (perception + reaction), then braking at
    ``brake_decel_mps2`` when > 0, else released; ``leader_*``: a scripted braking leader's plan; ``on_release`` gets
    the time it kept its speed [s]."""

    follower: str
    leader: str
    start_s: float
    react_at_s: float
    brake_decel_mps2: float = 0.0
    leader_target_mps: float = float("nan")
    leader_decel_mps2: float = 0.0
    leader_brake_end_s: float = -1.0
    on_release: Callable[[float], None] | None = None
    braking_since_s: float = float("nan")


@dataclass
class Reactions:
    """The followers currently held; advance them with :meth:`step` after every simulation step."""

    sim: Any  # the libsumo module
    release_decel_mps2: float
    release_gap_m: float
    jerk_mps3: float
    holds: list[Hold]
    gap_to: Callable[[str, str], float | None]  # bumper gap follower -> a given vehicle ahead, None if not ahead

    def __contains__(self, vid: str) -> bool:
        return any(h.follower == vid for h in self.holds)

    def start(self, hold: Hold) -> None:
        """Begin a hold (it acts from the next step on)."""
        v = self.sim.vehicle
        v.setSpeedMode(hold.follower, SPEED_MODE_HOLD)
        v.setSpeed(hold.follower, float(v.getSpeed(hold.follower)))
        # A driver who has not perceived the situation does not start an evasive lane change
        # either (and two crossing lane changes are a contact SUMO's lane-change model misses).
        v.setLaneChangeMode(hold.follower, LC_MODE_FORCED)
        self.holds.append(hold)

    def _release(self, h: Hold, t: float) -> None:
        v = self.sim.vehicle
        v.setSpeed(h.follower, -1.0)
        v.setSpeedMode(h.follower, SPEED_MODE_DEFAULT)
        v.setLaneChangeMode(h.follower, LC_MODE_DEFAULT)
        if h.on_release is not None:
            kept = (h.braking_since_s if not np.isnan(h.braking_since_s) else t) - h.start_s
            h.on_release(round(kept, 2))

    def step(self, t: float, alive: Callable[[str], bool]) -> None:
        """Advance every hold at simulation time ``t`` (end of the step just done)."""
        keep: list[Hold] = []
        v = self.sim.vehicle
        for h in self.holds:
            if not alive(h.follower):
                continue
            v_f = float(v.getSpeed(h.follower))
            # Safety against both the vehicle it reacts to (e.g. one changing into its lane, which
            # SUMO may not list as its leader yet) and whatever SUMO sees as its leader.
            obstacles: list[tuple[str, float]] = []
            gap_r = self.gap_to(h.follower, h.leader) if alive(h.leader) else None
            if gap_r is not None:
                obstacles.append((h.leader, gap_r))
            leader = v.getLeader(h.follower, 200.0)
            if leader and leader[0] != "" and leader[0] != h.leader:
                obstacles.append((leader[0], float(leader[1]) + float(v.getMinGap(h.follower))))
            if not obstacles:
                self._release(h, t)  # nothing ahead any more
                continue
            leader_braking = h.leader in dict(obstacles) and t < h.leader_brake_end_s
            unsafe = False
            for lid, gap in obstacles:
                v_l = float(v.getSpeed(lid))
                if lid == h.leader and leader_braking:
                    d_l, v_end = h.leader_decel_mps2, h.leader_target_mps
                else:  # assume the leader keeps its current braking for one more second
                    d_l = max(0.0, -float(v.getAcceleration(lid)))
                    v_end = max(0.0, v_l - d_l)
                need = required_decel(gap, v_f, v_l, d_l, v_end) if (v_f > v_l or d_l > 0.0) else 0.0
                unsafe = unsafe or gap < self.release_gap_m or need > self.release_decel_mps2
            if unsafe:
                self._release(h, t)
                continue
            v_l = float(v.getSpeed(h.leader)) if gap_r is not None else v_f
            if np.isnan(h.braking_since_s):
                if t + 1e-9 < h.react_at_s:
                    keep.append(h)  # still perceiving / reacting: the set speed stays
                    continue
                if h.brake_decel_mps2 <= 0.0:
                    self._release(h, t)
                    continue
                h.braking_since_s = t
                v.setSpeedMode(h.follower, SPEED_MODE_BRAKE)
            elif not leader_braking and (v_f <= v_l or t - h.braking_since_s > _MAX_BRAKING_S):
                self._release(h, t)
                continue
            # Brake with a jerk-limited ramp up to the driver's deceleration.
            decel = min(h.brake_decel_mps2, self.jerk_mps3 * (t - h.braking_since_s + STEP_S))
            v.setSpeed(h.follower, max(0.0, v_f - decel * STEP_S))
            keep.append(h)
        self.holds = keep
