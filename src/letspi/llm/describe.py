"""Scenario -> compact text for the prompts (paper §III-C inputs E, N, G_f, L).

``describe_scenario`` turns one scenario of a ``ScenarioBatch`` (ego frame at t = 0) and a predicted goal
into a ``ScenarioDescription``, rounded to one decimal (input tokens cost prefill). Lanes carry their HighD
ids; neighbour relations (``ahead``, ``left-behind``, ``2-left-alongside``...) come from the markings and
longitudinal box overlap, not from HighD's id columns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np

from letspi.constants import DT_S, T0_INDEX
from letspi.scenario.types import VEHICLE_CLASS_NAMES, ScenarioBatch

#: Same-lane TTC (s) or time gap (s) below which guidance calls a situation "closing".
CLOSING_TTC_S: Final = 5.0
SHORT_TIME_GAP_S: Final = 1.0
#: Adjacent-lane vehicles within this longitudinal gap (m) count as "near" for guidance.
LATERAL_NEAR_M: Final = 10.0


def _f(v: float) -> str:
    """One decimal, no negative zero."""
    s = f"{v:.1f}"
    return "0.0" if s == "-0.0" else s


@dataclass(frozen=True)
class LaneInfo:
    """One lane of the ego's carriageway."""

    lane_id: int
    right_y: float
    left_y: float
    right_is_edge: bool
    left_is_edge: bool

    @property
    def centre_y(self) -> float:
        return 0.5 * (self.right_y + self.left_y)


@dataclass(frozen=True)
class TrackPoint:
    """A sampled past position: time (s, negative), position (m), lane id."""

    t: float
    x: float
    y: float
    lane: int


@dataclass(frozen=True)
class NeighbourInfo:
    """A neighbour visible at t = 0 (ego-frame position and velocity, relative quantities)."""

    vehicle_id: int
    vehicle_class: str
    relation: str
    lane: int
    x: float
    y: float
    vx: float
    vy: float
    length: float
    width: float
    gap_m: float
    ttc_s: float | None
    history: tuple[TrackPoint, ...]
    rel_vx: float
    rel_vy: float

    @property
    def lane_offset(self) -> int:
        """Lanes to the left of the ego (negative = right)."""
        if self.relation.startswith(("left", "right")):
            return 1 if self.relation.startswith("left") else -1
        if self.relation[0].isdigit():
            n = int(self.relation.split("-")[0])
            return n if "-left-" in self.relation else -n
        return 0


@dataclass(frozen=True)
class ScenarioDescription:
    """Everything the prompts say about one scenario (ego frame, SI units)."""

    scenario_id: str
    location_id: int
    speed_limit_mps: float | None
    lanes: tuple[LaneInfo, ...]
    ego_lane: int
    ego_class: str
    ego_length: float
    ego_width: float
    ego_history: tuple[TrackPoint, ...]
    ego_x: float
    ego_y: float
    ego_vx: float
    ego_vy: float
    ego_ax: float
    neighbours: tuple[NeighbourInfo, ...]
    goal_x: float
    goal_y: float
    goal_lane: int
    horizon_s: float

    @property
    def ego_speed(self) -> float:
        return math.hypot(self.ego_vx, self.ego_vy)

    def lane_left_of(self, lane_id: int) -> int | None:
        """The lane to the left of ``lane_id`` (None at the left edge)."""
        ids = [ln.lane_id for ln in self.lanes]  # ordered right to left
        k = ids.index(lane_id) if lane_id in ids else -1
        return ids[k + 1] if 0 <= k < len(ids) - 1 else None

    def lane_right_of(self, lane_id: int) -> int | None:
        """The lane to the right of ``lane_id`` (None at the right edge)."""
        ids = [ln.lane_id for ln in self.lanes]
        k = ids.index(lane_id) if lane_id in ids else -1
        return ids[k - 1] if k > 0 else None

    def leader(self) -> NeighbourInfo | None:
        """The closest same-lane vehicle ahead."""
        ahead = [n for n in self.neighbours if n.relation == "ahead"]
        return min(ahead, key=lambda n: n.x) if ahead else None

    def follower(self) -> NeighbourInfo | None:
        """The closest same-lane vehicle behind."""
        behind = [n for n in self.neighbours if n.relation == "behind"]
        return max(behind, key=lambda n: n.x) if behind else None

    # --- text ---------------------------------------------------------------------------
    def summary_line(self) -> str:
        """One line for few-shot examples and memory retrieval logs."""
        lead = self.leader()
        lead_txt = f"leader gap {_f(lead.gap_m)} m, rel vx {_f(lead.rel_vx)}" if lead else "no leader"
        near = [n for n in self.neighbours if n is not lead][:1]  # sorted by distance
        near_txt = "".join(f", nearest other: {o.relation} at {_f(math.hypot(o.x, o.y))} m" for o in near)
        return (
            f"{len(self.lanes)} lanes, ego lane {self.ego_lane}, speed {_f(self.ego_speed)} m/s, "
            f"{len(self.neighbours)} neighbours, {lead_txt}{near_txt}"
        )

    def to_text(self, *, detail: str = "full") -> str:
        """Render for a prompt. ``detail="brief"`` drops histories and markings (fast prompt)."""
        full = detail == "full"
        return "\n".join([
            *self._road_lines(full),
            *self._ego_lines(full),
            f"## Neighbours at t=0 ({len(self.neighbours)})",
            *(["None within range."] if not self.neighbours else []),
            *(_neighbour_line(n, full) for n in self.neighbours),
            *self._goal_lines(),
        ])

    def _road_lines(self, full: bool) -> list[str]:
        limit = "none" if self.speed_limit_mps is None else f"{_f(self.speed_limit_mps)} m/s"
        lanes_l2r = list(reversed(self.lanes))
        lane_txt = ", ".join(
            f"{ln.lane_id} (y {_f(ln.right_y)}..{_f(ln.left_y)}, centre {_f(ln.centre_y)}"
            + (", ego" if ln.lane_id == self.ego_lane else "")
            + ")"
            for ln in lanes_l2r
        )
        out = [
            "## Scenario summary",
            f"Scenario {self.scenario_id}, location {self.location_id}: {len(self.lanes)} lanes in the "
            f"ego's direction, speed limit {limit}.",
            f"Lanes left to right: {lane_txt}.",
        ]
        if full:
            marks = [(ln.left_y, ln.left_is_edge) for ln in lanes_l2r]
            marks.append((lanes_l2r[-1].right_y, lanes_l2r[-1].right_is_edge))
            out.append(
                "Markings: "
                + ", ".join(f"y={_f(y)} {'edge (never cross)' if e else 'line (crossable)'}" for y, e in marks)
                + "."
            )
        return out

    def _ego_lines(self, full: bool) -> list[str]:
        out = [f"## Ego ({self.ego_class} {_f(self.ego_length)}x{_f(self.ego_width)} m)"]
        if full and self.ego_history:
            out.append(
                "History t: (x, y) lane: "
                + "; ".join(f"{_f(p.t)} s: ({_f(p.x)}, {_f(p.y)}) {p.lane}" for p in self.ego_history)
            )
        out.append(
            f"Now t=0: pos ({_f(self.ego_x)}, {_f(self.ego_y)}), vel ({_f(self.ego_vx)}, {_f(self.ego_vy)}) m/s, "
            f"acc {_f(self.ego_ax)} m/s^2, lane {self.ego_lane}."
        )
        return out

    def _goal_lines(self) -> list[str]:
        left = self.lane_left_of(self.goal_lane)
        right = self.lane_right_of(self.goal_lane)
        return [
            "## Goal",
            f"Predicted goal at t={_f(self.horizon_s)} s: ({_f(self.goal_x)}, {_f(self.goal_y)}), "
            f"lane {self.goal_lane}.",
            f"Goal lane shift: lane=-1 -> lane {left if left is not None else 'none (do not go left)'}, "
            f"lane=+1 -> lane {right if right is not None else 'none (do not go right)'}.",
        ]


def _neighbour_line(n: NeighbourInfo, full: bool) -> str:
    """One neighbour for ``ScenarioDescription.to_text``."""
    line = (
        f"#{n.vehicle_id} {n.vehicle_class} {_f(n.length)} m, {n.relation}, lane {n.lane}: "
        f"pos ({_f(n.x)}, {_f(n.y)}), vel ({_f(n.vx)}, {_f(n.vy)}), rel vel ({_f(n.rel_vx)}, {_f(n.rel_vy)})"
    )
    if n.relation in ("ahead", "behind", "alongside"):
        line += f", gap {_f(n.gap_m)} m"
        line += f", TTC {_f(n.ttc_s)} s" if n.ttc_s is not None else ", not closing"
    if full and n.history:
        line += "; past " + ", ".join(f"{_f(p.t)} s ({_f(p.x)}, {_f(p.y)})" for p in n.history)
    return line


def targeted_guidance(desc: ScenarioDescription) -> list[str]:
    """Short scenario-specific hints for the fast prompt (paper §III-E, Fast Prompt)."""
    hints: list[str] = []
    lead = desc.leader()
    if lead is not None:
        time_gap = lead.gap_m / max(desc.ego_speed, 0.1)
        if (lead.ttc_s is not None and lead.ttc_s < CLOSING_TTC_S) or time_gap < SHORT_TIME_GAP_S:
            hints.append(
                f"Closing on the preceding vehicle #{lead.vehicle_id} (gap {_f(lead.gap_m)} m"
                + (f", TTC {_f(lead.ttc_s)} s" if lead.ttc_s is not None else "")
                + "): raise k_np and shorten the goal (lon 0.6-1.0)."
            )
    fol = desc.follower()
    if fol is not None and fol.ttc_s is not None and fol.ttc_s < CLOSING_TTC_S:
        hints.append(
            f"Vehicle #{fol.vehicle_id} closing from behind (TTC {_f(fol.ttc_s)} s): "
            "raise k_nf, do not shorten the goal."
        )
    for n in desc.neighbours:
        if abs(n.lane_offset) == 1 and abs(n.x) < LATERAL_NEAR_M + 0.5 * (desc.ego_length + n.length):
            side = "left" if n.lane_offset > 0 else "right"
            hints.append(f"Vehicle #{n.vehicle_id} beside on the {side}: raise k_nl and keep the lane (lane 0).")
    if desc.lane_left_of(desc.ego_lane) is None:
        hints.append("No lane to the left: lane must not be negative.")
    if desc.lane_right_of(desc.ego_lane) is None:
        hints.append("No lane to the right: lane must not be positive.")
    if not hints or (len(hints) <= 2 and all(h.startswith("No lane") for h in hints)):
        hints.append("No conflict: moderate parameters, keep the goal (lon about 0.4, lane 0).")
    return hints


# --- construction ---------------------------------------------------------------------------


@dataclass(frozen=True)
class _Road:
    """The ego's carriageway of one scenario: its lanes (right to left) and the marking positions."""

    lanes: tuple[LaneInfo, ...]
    marking_y: np.ndarray  # (L + 1,) finite marking y [m], right to left

    def lane_index(self, y: float) -> int:
        """Index of the lane (0 = rightmost) containing y, clipped to the road."""
        return int(np.clip(np.searchsorted(self.marking_y, y, side="right") - 1, 0, len(self.marking_y) - 2))

    def lane_id(self, y: float) -> int:
        return self.lanes[self.lane_index(y)].lane_id


def _road(batch: ScenarioBatch, index: int) -> _Road:
    ys = np.asarray(batch.marking_y_m[index], dtype=float)
    ok = np.isfinite(ys)
    ys = ys[ok]
    edges = np.asarray(batch.marking_is_edge[index], dtype=bool)[ok]
    ids = np.asarray(batch.lane_ids[index])[: max(len(ys) - 1, 0)]
    lanes = tuple(
        LaneInfo(int(ids[k]), float(ys[k]), float(ys[k + 1]), bool(edges[k]), bool(edges[k + 1]))
        for k in range(len(ys) - 1)
    )
    if not lanes:
        raise ValueError(f"scenario {batch.scenario_id[index]}: needs at least two lane markings")
    return _Road(lanes, ys)


def _relation(offset: int, dx: float, overlap_half: float) -> str:
    lon = "alongside" if abs(dx) < overlap_half else ("ahead" if dx > 0 else "behind")
    if offset == 0:
        return lon
    side = "left" if offset > 0 else "right"
    return f"{side}-{lon}" if abs(offset) == 1 else f"{abs(offset)}-{side}-{lon}"


def _sample_indices(step_s: float) -> list[int]:
    """History frame indices every ``step_s`` before t = 0 (oldest first), excluding t = 0."""
    out = []
    k = 1
    while True:
        # ceil: at 25 Hz, 0.5 s is 12.5 frames; always take the older frame (consistent spacing)
        idx = T0_INDEX - math.ceil(k * step_s / DT_S - 1e-9)
        if idx < 0:
            break
        out.append(int(idx))
        k += 1
    return out[::-1]


def _track(road: _Road, xy: np.ndarray, frames: list[int], seen: np.ndarray) -> tuple[TrackPoint, ...]:
    """Past positions ``xy`` (T, 2) at ``frames`` where ``seen`` (T,) and finite, with their lanes."""
    return tuple(
        TrackPoint((i - T0_INDEX) * DT_S, float(xy[i, 0]), float(xy[i, 1]), road.lane_id(float(xy[i, 1])))
        for i in frames
        if seen[i] and np.all(np.isfinite(xy[i]))
    )


@dataclass(frozen=True)
class _Ego:
    """The ego at t = 0: position (m), velocity (m/s), lane index on the road, box (m)."""

    x: float
    y: float
    vx: float
    vy: float
    lane_index: int
    length: float


def _neighbour(batch: ScenarioBatch, index: int, j: int, road: _Road, ego: _Ego,
               history_frames: list[int]) -> NeighbourInfo | None:
    """Neighbour slot ``j`` at t = 0 relative to the ego (None when it is not visible then)."""
    t0 = T0_INDEX
    valid = np.asarray(batch.nbr_valid[index][j], dtype=bool)
    nxy = np.asarray(batch.nbr_xy_m[index][j], dtype=float)
    nv = np.asarray(batch.nbr_vxy_mps[index][j], dtype=float)
    if not valid[t0] or not np.all(np.isfinite(nxy[t0])):
        return None
    x, y = float(nxy[t0, 0]), float(nxy[t0, 1])
    vx, vy = (float(nv[t0, 0]), float(nv[t0, 1])) if np.all(np.isfinite(nv[t0])) else (0.0, 0.0)
    length, width = float(batch.nbr_length_m[index][j]), float(batch.nbr_width_m[index][j])
    k = road.lane_index(y)
    dx, dy = x - ego.x, y - ego.y
    half = 0.5 * (ego.length + length)
    gap = abs(dx) - half
    closing = (ego.vx - vx) if dx > 0 else (vx - ego.vx)
    ttc = gap / closing if (k == ego.lane_index and gap > 0 and closing > 1e-6) else None
    if k == ego.lane_index and gap <= 0:
        ttc = 0.0  # overlapping boxes in one lane: contact now
    return NeighbourInfo(
        vehicle_id=int(batch.nbr_id[index][j]),
        vehicle_class=VEHICLE_CLASS_NAMES.get(int(batch.nbr_class[index][j]), "vehicle").lower(),
        relation=_relation(k - ego.lane_index, dx, half), lane=road.lanes[k].lane_id,
        x=dx, y=dy, vx=vx, vy=vy, length=length, width=width, gap_m=gap, ttc_s=ttc,
        history=_track(road, nxy, history_frames, valid), rel_vx=vx - ego.vx, rel_vy=vy - ego.vy,
    )


def describe_scenario(batch: ScenarioBatch, goal_xy: tuple[float, float] | np.ndarray, *, index: int = 0,
                      history_step_s: float = 0.5, neighbour_history_step_s: float = 1.0,
                      horizon_s: float = 5.0) -> ScenarioDescription:
    """The description of scenario ``index`` at t = 0 with the predicted ``goal_xy`` (ego frame); frames up to t = 0."""
    road = _road(batch, index)
    t0 = T0_INDEX
    ego_xy = np.asarray(batch.ego_xy_m[index], dtype=float)
    ego_v = np.asarray(batch.ego_vxy_mps[index], dtype=float)
    ego_a = np.asarray(batch.ego_axy_mps2[index], dtype=float)
    ego = _Ego(float(ego_xy[t0, 0]), float(ego_xy[t0, 1]), float(ego_v[t0, 0]), float(ego_v[t0, 1]),
               road.lane_index(float(ego_xy[t0, 1])), float(batch.ego_length_m[index]))
    nbr_frames = _sample_indices(neighbour_history_step_s)[-2:]  # short: the last two samples
    found = (_neighbour(batch, index, j, road, ego, nbr_frames) for j in range(batch.nbr_valid[index].shape[0]))
    nbrs = sorted((n for n in found if n is not None), key=lambda n: math.hypot(n.x, n.y))
    gx, gy = float(goal_xy[0]), float(goal_xy[1])
    limit = float(batch.speed_limit_mps[index])
    return ScenarioDescription(
        scenario_id=str(batch.scenario_id[index]),
        location_id=int(batch.location_id[index]),
        speed_limit_mps=limit if math.isfinite(limit) and limit > 0 else None,
        lanes=road.lanes,
        ego_lane=road.lanes[ego.lane_index].lane_id,
        ego_class=VEHICLE_CLASS_NAMES.get(int(batch.ego_class[index]), "vehicle").lower(),
        ego_length=ego.length,
        ego_width=float(batch.ego_width_m[index]),
        ego_history=_track(road, ego_xy, _sample_indices(history_step_s), np.ones(len(ego_xy), dtype=bool)),
        ego_x=ego.x, ego_y=ego.y, ego_vx=ego.vx, ego_vy=ego.vy,
        ego_ax=float(ego_a[t0, 0]) if np.isfinite(ego_a[t0, 0]) else 0.0,
        neighbours=tuple(nbrs),
        goal_x=gx, goal_y=gy, goal_lane=road.lane_id(gy),
        horizon_s=horizon_s,
    )
