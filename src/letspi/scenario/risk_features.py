"""History features of risk: what the 3 s history says about the next seconds (observable at t = 0).

``risk_features`` (B, ``len(RISK_FEATURE_NAMES)``) float64, always finite; columns in that order, units as named:
ego speed, longitudinal acceleration, |lateral speed|; the **leader** (nearest ahead in the ego's lane): bumper
gap, closing speed (> 0 closing), its acceleration over the last ``RECENT_S``, time headway (capped at
``THW_CAP_S``), inverse TTC (>= 0); the **second vehicle ahead** (a braking wave shows there first): gap to the
leader, the leader's closing speed on it, its acceleration; the **follower**: gap, closing speed; the adjacent
vehicle moving fastest towards the ego lane within ``ADJACENT_RANGE_M``: lateral speed, longitudinal offset;
bumper gaps to the nearest vehicle ahead and behind in the left and the right lane; vehicles visible at t = 0.
A missing vehicle gets a gap of ``FAR_M`` and zero relative speeds; a missing lane gaps of 0 (no room).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from letspi.constants import DT_S, T0_INDEX
from letspi.scenario.queries import OFF_ROAD, lane_index_of
from letspi.scenario.types import ScenarioBatch

FAR_M: Final = 150.0
THW_CAP_S: Final = 10.0
RECENT_S: Final = 0.5
ADJACENT_RANGE_M: Final = (-30.0, 80.0)
RISK_FEATURE_NAMES: Final[tuple[str, ...]] = (
    "ego_speed_mps", "ego_ax_mps2", "ego_lateral_mps",
    "leader_gap_m", "leader_closing_mps", "leader_ax_mps2", "leader_thw_s", "leader_inv_ttc_1ps",
    "second_gap_m", "second_closing_mps", "second_ax_mps2",
    "follower_gap_m", "follower_closing_mps",
    "adjacent_towards_mps", "adjacent_towards_dx_m",
    "left_ahead_gap_m", "left_behind_gap_m", "right_ahead_gap_m", "right_behind_gap_m",
    "n_vehicles",
)


def _nearest(mask: np.ndarray, key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(slot (B,), found (B,)) of the smallest ``key`` where ``mask`` (B, N)."""
    k = np.where(mask, key, np.inf)
    slot = np.argmin(k, axis=1)
    return slot, np.isfinite(k[np.arange(len(slot)), slot])


@dataclass(frozen=True)
class _Observed:
    """t = 0 quantities (B, N) of the neighbours relative to the ego, and the ego's own (B,)."""

    x: np.ndarray
    y: np.ndarray
    vx: np.ndarray
    ax: np.ndarray
    length: np.ndarray
    seen: np.ndarray
    lane: np.ndarray
    ego_lane: np.ndarray  # (B, 1)
    gap: np.ndarray
    ego_speed: np.ndarray

    @property
    def same(self) -> np.ndarray:
        return self.seen & (self.lane == self.ego_lane) & (self.ego_lane != OFF_ROAD)


def _observed(batch: ScenarioBatch, n_recent: int) -> _Observed:
    x = batch.nbr_xy_m[:, :, T0_INDEX, 0].astype(np.float64)
    y = batch.nbr_xy_m[:, :, T0_INDEX, 1].astype(np.float64)
    vx = batch.nbr_vxy_mps[:, :, T0_INDEX, 0].astype(np.float64)
    vx_before = batch.nbr_vxy_mps[:, :, T0_INDEX - n_recent, 0].astype(np.float64)
    seen = batch.nbr_valid[:, :, T0_INDEX] & np.isfinite(x) & np.isfinite(y) & np.isfinite(vx)
    ax = np.where(np.isfinite(vx_before) & batch.nbr_valid[:, :, T0_INDEX - n_recent],
                  (vx - vx_before) / (n_recent * DT_S), 0.0)
    marking = batch.marking_y_m.astype(np.float64)
    length = np.nan_to_num(batch.nbr_length_m.astype(np.float64))
    half = 0.5 * (length + batch.ego_length_m.astype(np.float64)[:, None])
    return _Observed(
        x=x, y=y, vx=vx, ax=ax, length=length, seen=seen, lane=lane_index_of(marking, np.where(seen, y, np.nan)),
        ego_lane=lane_index_of(marking, np.nan_to_num(batch.ego_xy_m[:, T0_INDEX, 1:2].astype(np.float64))),
        gap=np.abs(x) - half, ego_speed=np.nan_to_num(batch.ego_vxy_mps[:, T0_INDEX, 0].astype(np.float64)),
    )


def _in_lane_features(o: _Observed) -> list[np.ndarray]:
    """Leader (gap, closing, acceleration, headway, inverse TTC), 2nd ahead (gap, closing, acceleration), follower."""
    rows = np.arange(len(o.x))
    lead, has_lead = _nearest(o.same & (o.x > 0), o.x)
    lead_gap = np.where(has_lead, o.gap[rows, lead], FAR_M)
    lead_v = o.vx[rows, lead]
    lead_close = np.where(has_lead, o.ego_speed - lead_v, 0.0)
    thw = np.where(has_lead, np.clip(lead_gap / np.maximum(o.ego_speed, 0.1), 0.0, THW_CAP_S), THW_CAP_S)
    inv_ttc = np.where(has_lead, np.clip(lead_close, 0.0, None) / np.maximum(lead_gap, 0.5), 0.0)
    lead_x = o.x[rows, lead]
    second, has_second = _nearest(o.same & (o.x > lead_x[:, None]) & has_lead[:, None], o.x)
    sec_gap = np.where(has_second, o.x[rows, second] - lead_x - 0.5 * (o.length[rows, second] + o.length[rows, lead]),
                       FAR_M)
    foll, has_foll = _nearest(o.same & (o.x <= 0), -o.x)
    return [
        np.clip(lead_gap, -10.0, FAR_M), lead_close, np.where(has_lead, o.ax[rows, lead], 0.0), thw, inv_ttc,
        np.clip(sec_gap, -10.0, FAR_M), np.where(has_second, lead_v - o.vx[rows, second], 0.0),
        np.where(has_second, o.ax[rows, second], 0.0),
        np.clip(np.where(has_foll, o.gap[rows, foll], FAR_M), -10.0, FAR_M),
        np.where(has_foll, o.vx[rows, foll] - o.ego_speed, 0.0),
    ]


def _side_features(o: _Observed, batch: ScenarioBatch, n_recent: int) -> list[np.ndarray]:
    """The adjacent vehicle moving fastest towards the ego lane (lateral speed, dx) and the bumper gaps
    ahead / behind in the left and the right lane."""
    rows = np.arange(len(o.x))
    marking = batch.marking_y_m.astype(np.float64)
    centres = 0.5 * (marking[:, 1:] + marking[:, :-1])
    ego_centre = np.take_along_axis(centres, np.clip(o.ego_lane, 0, None), axis=1)  # (B, 1)
    vy_recent = batch.nbr_vxy_mps[:, :, T0_INDEX + 1 - n_recent:T0_INDEX + 1, 1].astype(np.float64)
    vy_ok = np.isfinite(vy_recent)
    vy_mean = np.where(vy_ok, vy_recent, 0.0).sum(axis=2) / np.maximum(vy_ok.sum(axis=2), 1)
    towards = np.nan_to_num(vy_mean * np.sign(ego_centre - o.y))
    adjacent = o.seen & (np.abs(o.lane - o.ego_lane) == 1) & (o.ego_lane != OFF_ROAD)
    in_range = adjacent & (o.x >= ADJACENT_RANGE_M[0]) & (o.x <= ADJACENT_RANGE_M[1])
    cut, has_cut = _nearest(in_range, -towards)
    adj_towards = np.where(has_cut, np.clip(towards[rows, cut], 0.0, None), 0.0)
    out = [adj_towards, np.where(has_cut & (adj_towards > 0), o.x[rows, cut], FAR_M)]
    n_lanes = np.isfinite(marking).sum(axis=1) - 1
    for offset in (+1, -1):  # lane indices grow to the left (markings ascend in y)
        target = o.ego_lane + offset
        in_lane = o.seen & (o.lane == target) & (o.ego_lane != OFF_ROAD)
        exists = (target[:, 0] >= 0) & (target[:, 0] < n_lanes)
        for mask, key in ((in_lane & (o.x > 0), o.x), (in_lane & (o.x <= 0), -o.x)):
            slot, found = _nearest(mask, key)
            gap = np.where(found, np.clip(o.gap[rows, slot], 0.0, FAR_M), FAR_M)
            out.append(np.where(exists, gap, 0.0))  # no lane: no room at all
    return out


def risk_features(batch: ScenarioBatch) -> np.ndarray:
    """(B, F) risk features of the observed scenes (columns in the module docstring; the history suffices)."""
    n_recent = max(round(RECENT_S / DT_S), 1)
    o = _observed(batch, n_recent)
    ego_v = np.nan_to_num(batch.ego_vxy_mps[:, T0_INDEX].astype(np.float64))
    ego_ax = np.nan_to_num(batch.ego_axy_mps2[:, T0_INDEX, 0].astype(np.float64))
    out = np.stack([o.ego_speed, ego_ax, np.abs(ego_v[:, 1]), *_in_lane_features(o),
                    *_side_features(o, batch, n_recent), o.seen.sum(axis=1).astype(np.float64)], axis=1)
    return np.nan_to_num(out, nan=0.0, posinf=FAR_M, neginf=-FAR_M)
