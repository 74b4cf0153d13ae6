"""What the pictures draw, computed from a scenario and its plans (no Matplotlib here)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from letspi.constants import DT_S, N_TOTAL, T0_INDEX
from letspi.planners.base import PlanBatch
from letspi.scenario.queries import OFF_ROAD, lane_index_of
from letspi.scenario.types import ScenarioBatch

SAME_LANE = "same lane"
ADJACENT_LANE = "adjacent lane"
OTHER_LANE = "other lane"


@dataclass(frozen=True)
class PlanTrack:
    """One planner's plan for one scenario, ego frame: ``name`` (legend label, gid suffix), ``xy_m`` (F, 2) [m] at
    frames 1..F after t = 0, ``vxy_mps`` (F, 2) [m/s], ``goal_xy_m`` (2,) [m] (possibly adjusted; NaN: none)."""

    name: str
    xy_m: np.ndarray
    vxy_mps: np.ndarray
    goal_xy_m: np.ndarray

    @property
    def t_s(self) -> np.ndarray:
        """Times of the plan's points after t = 0 [s]: (k + 1) * dt."""
        return (np.arange(len(self.xy_m)) + 1) * DT_S


def plan_track(name: str, plan: PlanBatch, row: int = 0) -> PlanTrack:
    """The ``row``-th scenario of ``plan`` as a ``PlanTrack`` (arrays copied as float64)."""
    return PlanTrack(
        name=name,
        xy_m=np.asarray(plan.xy_m[row], dtype=np.float64),
        vxy_mps=np.asarray(plan.vxy_mps[row], dtype=np.float64),
        goal_xy_m=np.asarray(plan.goals_xy_m[row], dtype=np.float64),
    )


def plan_tracks(plans: Mapping[str, PlanBatch] | None, index: int, batch_size: int) -> list[PlanTrack]:
    """Plans for scenario ``index`` of a batch of ``batch_size``: each ``PlanBatch`` holds that scenario
    alone (B = 1) or the whole batch (row ``index`` is used); anything else is a ``ValueError``."""
    out: list[PlanTrack] = []
    for name, plan in (plans or {}).items():
        b = plan.xy_m.shape[0]
        if b == 1:
            out.append(plan_track(name, plan, 0))
        elif b == batch_size:
            out.append(plan_track(name, plan, index))
        else:
            raise ValueError(f"plan {name!r} holds {b} scenarios; expected 1 or the batch size {batch_size}")
    return out


def times_s() -> np.ndarray:
    """Time of every scenario frame relative to t = 0 [s], (N_TOTAL,)."""
    return (np.arange(N_TOTAL) - T0_INDEX) * DT_S


def _lane_index(scenario: ScenarioBatch, y_m: np.ndarray) -> np.ndarray:
    y = np.asarray(y_m, dtype=np.float64)
    return lane_index_of(np.asarray(scenario.marking_y_m[0], dtype=np.float64)[None, :], y[None, ...])[0]


def neighbour_groups(scenario: ScenarioBatch) -> list[str | None]:
    """Per neighbour slot: ``SAME_LANE``, ``ADJACENT_LANE``, ``OTHER_LANE`` relative to the ego's lane at t = 0 (the
    neighbour's lane then, or at its first visible frame), or None for empty slots."""
    ego_lane = int(_lane_index(scenario, np.array([scenario.ego_xy_m[0][T0_INDEX, 1]]))[0])
    groups: list[str | None] = []
    for j in range(len(scenario.nbr_id[0])):
        valid = np.asarray(scenario.nbr_valid[0][j], dtype=bool)
        if not valid.any():
            groups.append(None)
            continue
        frame = T0_INDEX if valid[T0_INDEX] else int(np.flatnonzero(valid)[0])
        lane = int(_lane_index(scenario, np.array([scenario.nbr_xy_m[0][j, frame, 1]]))[0])
        if ego_lane == OFF_ROAD or lane == OFF_ROAD:
            groups.append(OTHER_LANE)
        elif lane == ego_lane:
            groups.append(SAME_LANE)
        elif abs(lane - ego_lane) == 1:
            groups.append(ADJACENT_LANE)
        else:
            groups.append(OTHER_LANE)
    return groups


def preceding_gap(scenario: ScenarioBatch, ego_xy_m: np.ndarray, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gap from the ego (``ego_xy_m`` (K, 2) at scenario ``frames`` (K,)) to the vehicle ahead in its lane, from the
    neighbours' recorded positions. Returns ``gap_m`` (K,), ``dx - (L_ego + L_nbr) / 2`` (negative: overlapping; NaN:
    no leader), and ``leader_slot`` (K,), -1 where none."""
    ego = np.asarray(ego_xy_m, dtype=np.float64)
    frames = np.asarray(frames, dtype=np.int64)
    nbr = np.asarray(scenario.nbr_xy_m[0], dtype=np.float64)[:, frames]  # (N, K, 2)
    valid = np.asarray(scenario.nbr_valid[0], dtype=bool)[:, frames]
    ego_lane = _lane_index(scenario, ego[:, 1])  # (K,)
    nbr_lane = _lane_index(scenario, nbr[..., 1].T).T  # (N, K)
    dx = nbr[..., 0] - ego[None, :, 0]
    ahead = valid & (nbr_lane == ego_lane[None, :]) & (ego_lane[None, :] != OFF_ROAD) & (dx > 0)
    key = np.where(ahead, dx, np.inf)
    slot = np.argmin(key, axis=0)
    k = np.arange(len(frames))
    found = np.isfinite(key[slot, k])
    half = 0.5 * (float(scenario.ego_length_m[0]) + np.asarray(scenario.nbr_length_m[0], dtype=np.float64)[slot])
    gap = np.where(found, key[slot, k] - half, np.nan)
    return gap, np.where(found, slot, -1)
