"""Adverse futures: plausible events the (calm) neighbour prediction does not foresee, from the history only.

``leader-brakes``: the nearest vehicle ahead within ``brake_range_m`` (bumper gap) in the ego's and each adjacent
lane brakes at ``brake_decel_mps2`` for ``brake_duration_s`` from t = 0, then keeps its speed. ``cut-in``: an
adjacent-lane vehicle whose mean lateral speed over the last ``lateral_window_s`` points to the ego lane (>=
``cut_in_min_lateral_mps``) moves to its centre at the larger of that speed and ``cut_in_lateral_mps`` (x as
predicted). ``follower-keeps``: vehicles behind within ``follower_range_m`` (ego and adjacent lanes) keep their
t = 0 speed. A future without an actor equals the base (``AdverseFutures.applies``). ``FutureChecks.failed``
applies laxer thresholds: an adverse event may make a plan uncomfortable, not make it collide."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Final

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from letspi.constants import DT_S, T0_INDEX
from letspi.metrics.collision import boxes_overlap
from letspi.physics.types import NeighbourPrediction
from letspi.safety.plan_check import SafetyCheck, check_inputs, predicted_inputs
from letspi.scenario.queries import OFF_ROAD, lane_index_of
from letspi.scenario.types import ScenarioBatch


class AdverseFuture(StrEnum):
    """The adverse futures, by the names the reports, prompts and per-scenario results use."""

    LEADER_BRAKES = "leader-brakes"
    CUT_IN = "cut-in"
    FOLLOWER_KEEPS = "follower-keeps"


ADVERSE_FUTURES: Final[tuple[AdverseFuture, ...]] = tuple(AdverseFuture)
#: the name of the base prediction in ``FutureChecks.names``
PREDICTED: Final = "predicted"


class AdverseSettings(BaseModel):
    """How the adverse futures are derived and judged (part of every configuration key that uses them)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    futures: tuple[AdverseFuture, ...] = ADVERSE_FUTURES
    brake_decel_mps2: float = Field(default=6.0, gt=0)
    brake_duration_s: float = Field(default=2.0, gt=0)
    brake_range_m: float = Field(default=60.0, gt=0)
    cut_in_min_lateral_mps: float = Field(default=0.3, gt=0)
    cut_in_lateral_mps: float = Field(default=0.94, gt=0)
    cut_in_range_m: tuple[float, float] = (-30.0, 80.0)
    lateral_window_s: float = Field(default=0.5, gt=0)
    follower_range_m: float = Field(default=60.0, gt=0)
    #: an adverse future fails a plan on contact, a front or rear TTC below ``ttc_s`` or an in-path
    #: gap below ``min_gap_m`` (laxer than the reflection's thresholds: the event is adverse)
    ttc_s: float = Field(default=0.5, ge=0)
    min_gap_m: float = Field(default=0.5, ge=0)


@dataclass(frozen=True)
class AdverseFutures:
    """Adverse variants of a prediction: ``names`` (A,) in ``AdverseSettings.futures`` order; ``xy_m``, ``vxy_mps``
    (A, B, N, F, 2) and ``valid`` (A, B, N, F); ``applies`` (A, B): the future differs from the base there."""

    names: tuple[str, ...]
    xy_m: np.ndarray
    vxy_mps: np.ndarray
    valid: np.ndarray
    applies: np.ndarray

    def prediction(self, a: int) -> NeighbourPrediction:
        """Future ``a`` as a (B, N, F, ...) prediction."""
        return NeighbourPrediction(self.xy_m[a], self.vxy_mps[a], self.valid[a])

    def take(self, indices: np.ndarray | list[int] | slice) -> AdverseFutures:
        """The futures of a sub-batch."""
        return AdverseFutures(self.names, self.xy_m[:, indices], self.vxy_mps[:, indices], self.valid[:, indices],
                              self.applies[:, indices])


def _recent_lateral_mps(batch: ScenarioBatch, window_s: float) -> np.ndarray:
    """(B, N) mean lateral speed of each neighbour over the last ``window_s`` of history (NaN unknown)."""
    n = max(round(window_s / DT_S), 1)
    sl = slice(T0_INDEX + 1 - n, T0_INDEX + 1)
    vy = batch.nbr_vxy_mps[:, :, sl, 1].astype(np.float64)
    ok = batch.nbr_valid[:, :, sl] & np.isfinite(vy)
    count = ok.sum(axis=2)
    return np.where(count > 0, np.where(ok, vy, 0.0).sum(axis=2) / np.maximum(count, 1), np.nan)


@dataclass(frozen=True)
class _Scene:
    """What the futures are derived from: the base prediction (B, N, F, ...) and t = 0 states (B, N): ``x0``, ``y0``,
    ``vx0`` relative to the ego [m, m/s]; lane indices; ``near_lane`` (visible, in the ego's or an adjacent lane);
    ``bumper_gap`` [m]; ``ego_centre`` (B, 1) the ego lane's centre y [m]; ``t`` (F,) the future instants [s]."""

    xy: np.ndarray
    vxy: np.ndarray
    x0: np.ndarray
    y0: np.ndarray
    vx0: np.ndarray
    lane: np.ndarray
    ego_lane: np.ndarray
    near_lane: np.ndarray
    bumper_gap: np.ndarray
    ego_centre: np.ndarray
    t: np.ndarray


def _scene(batch: ScenarioBatch, base: NeighbourPrediction) -> _Scene:
    xy = np.asarray(base.xy_m, dtype=np.float64)
    valid = np.asarray(base.valid, dtype=bool)
    x0 = batch.nbr_xy_m[:, :, T0_INDEX, 0].astype(np.float64)
    y0 = batch.nbr_xy_m[:, :, T0_INDEX, 1].astype(np.float64)
    vx0 = batch.nbr_vxy_mps[:, :, T0_INDEX, 0].astype(np.float64)
    seen = batch.nbr_valid[:, :, T0_INDEX] & np.isfinite(x0) & np.isfinite(y0) & np.isfinite(vx0) & valid[:, :, 0]
    marking = batch.marking_y_m.astype(np.float64)
    ego_lane = lane_index_of(marking, batch.ego_xy_m[:, T0_INDEX, 1:2].astype(np.float64))  # (B, 1)
    lane = lane_index_of(marking, np.where(seen, y0, np.nan))  # (B, N)
    near_lane = seen & (ego_lane != OFF_ROAD) & (lane != OFF_ROAD) & (np.abs(lane - ego_lane) <= 1)
    half_len = 0.5 * (np.nan_to_num(batch.nbr_length_m.astype(np.float64))
                      + batch.ego_length_m.astype(np.float64)[:, None])
    centres = 0.5 * (marking[:, 1:] + marking[:, :-1])  # (B, M - 1)
    return _Scene(
        xy=xy, vxy=np.asarray(base.vxy_mps, dtype=np.float64), x0=x0, y0=y0, vx0=vx0, lane=lane, ego_lane=ego_lane,
        near_lane=near_lane, bumper_gap=np.abs(x0) - half_len,
        ego_centre=np.take_along_axis(centres, np.clip(ego_lane, 0, None), axis=1),
        t=np.arange(1, valid.shape[2] + 1) * DT_S,
    )


#: one future: (scene, history, settings) -> (xy (B, N, F, 2), vxy (B, N, F, 2), applies (B,))
_Variant = tuple[np.ndarray, np.ndarray, np.ndarray]


def _leader_brakes(sc: _Scene, batch: ScenarioBatch, s: AdverseSettings) -> _Variant:
    ahead = sc.near_lane & (sc.x0 > 0) & (sc.bumper_gap <= s.brake_range_m)
    # the nearest one ahead per lane: nobody ahead of the ego in its lane is closer
    key = np.where(ahead, sc.x0, np.inf)
    same_lane = sc.lane[:, :, None] == sc.lane[:, None, :]
    closer = (key[:, None, :] < key[:, :, None]) & same_lane & ahead[:, None, :]
    actor = ahead & ~closer.any(axis=2)  # (B, N)
    v0 = sc.vx0[..., None]
    v = np.maximum(v0 - s.brake_decel_mps2 * np.minimum(sc.t, s.brake_duration_s), 0.0)  # (B, N, F)
    # distance of piecewise-constant deceleration, exactly: the mean speed of each step
    dist = np.cumsum(0.5 * (np.concatenate([v0, v[..., :-1]], axis=-1) + v) * DT_S, axis=-1)
    xy, vxy = sc.xy.copy(), sc.vxy.copy()
    xy[..., 0] = np.where(actor[..., None], sc.x0[..., None] + dist, sc.xy[..., 0])
    vxy[..., 0] = np.where(actor[..., None], v, sc.vxy[..., 0])
    return xy, vxy, actor.any(axis=1)


def _cut_in(sc: _Scene, batch: ScenarioBatch, s: AdverseSettings) -> _Variant:
    towards = np.sign(sc.ego_centre - sc.y0)  # +1: the ego lane is on its left
    lateral = _recent_lateral_mps(batch, s.lateral_window_s) * towards
    lo, hi = s.cut_in_range_m
    actor = (sc.near_lane & (sc.lane != sc.ego_lane) & (lateral >= s.cut_in_min_lateral_mps)
             & (sc.x0 >= lo) & (sc.x0 <= hi))
    speed = np.maximum(np.nan_to_num(lateral), s.cut_in_lateral_mps)[..., None]  # (B, N, 1)
    span = np.abs(sc.ego_centre - sc.y0)[..., None]  # how far it has to go
    moved = np.minimum(speed * sc.t, span)  # (B, N, F)
    vy = np.where(speed * sc.t < span, speed, 0.0) * towards[..., None]
    xy, vxy = sc.xy.copy(), sc.vxy.copy()
    xy[..., 1] = np.where(actor[..., None], sc.y0[..., None] + towards[..., None] * moved, sc.xy[..., 1])
    vxy[..., 1] = np.where(actor[..., None], vy, sc.vxy[..., 1])
    return xy, vxy, actor.any(axis=1)


def _follower_keeps(sc: _Scene, batch: ScenarioBatch, s: AdverseSettings) -> _Variant:
    actor = (sc.near_lane & (sc.x0 < 0) & (sc.bumper_gap <= s.follower_range_m))[..., None]
    xy, vxy = sc.xy.copy(), sc.vxy.copy()
    xy[..., 0] = np.where(actor, sc.x0[..., None] + sc.vx0[..., None] * sc.t, sc.xy[..., 0])
    xy[..., 1] = np.where(actor, sc.y0[..., None], sc.xy[..., 1])
    vxy[..., 0] = np.where(actor, sc.vx0[..., None], sc.vxy[..., 0])
    vxy[..., 1] = np.where(actor, 0.0, sc.vxy[..., 1])
    return xy, vxy, np.any(actor[..., 0], axis=1)


_VARIANTS = {AdverseFuture.LEADER_BRAKES: _leader_brakes, AdverseFuture.CUT_IN: _cut_in,
             AdverseFuture.FOLLOWER_KEEPS: _follower_keeps}


def adverse_futures(batch: ScenarioBatch, base: NeighbourPrediction,
                    settings: AdverseSettings | None = None) -> AdverseFutures:
    """The adverse variants of ``base`` (B, N, F, ...) for the observed scenes ``batch`` (history suffices)."""
    s = settings or AdverseSettings()
    valid = np.asarray(base.valid, dtype=bool)
    xy = np.asarray(base.xy_m, dtype=np.float64)
    if not s.futures:  # no adverse future: empty arrays (checks against the prediction only)
        return AdverseFutures((), np.zeros((0, *xy.shape)), np.zeros((0, *xy.shape)), np.zeros((0, *valid.shape), bool),
                              np.zeros((0, len(batch)), dtype=bool))
    sc = _scene(batch, base)
    variants = [_VARIANTS[name](sc, batch, s) for name in s.futures]
    mask = valid[None, ..., None]
    return AdverseFutures(names=tuple(str(x) for x in s.futures),
                          xy_m=np.where(mask, np.stack([v[0] for v in variants]), 0.0),
                          vxy_mps=np.where(mask, np.stack([v[1] for v in variants]), 0.0),
                          valid=np.repeat(valid[None], len(s.futures), axis=0),
                          applies=np.stack([v[2] for v in variants]).reshape(len(s.futures), len(batch)))


@dataclass(frozen=True)
class FutureChecks:
    """Plans checked against the base prediction (column 0, ``PREDICTED``) and each adverse future: ``names`` (1 + A,);
    (B, 1 + A) ``collision``, ``min_ttc_s``, ``min_rear_ttc_s``, ``min_path_gap_m``, ``contact_time_s`` (NaN without),
    ``applies`` (column 0 always True); ``off_road`` (B,), the same in every future."""

    names: tuple[str, ...]
    off_road: np.ndarray
    collision: np.ndarray
    min_ttc_s: np.ndarray
    min_rear_ttc_s: np.ndarray
    min_path_gap_m: np.ndarray
    contact_time_s: np.ndarray
    applies: np.ndarray

    def failed(self, settings: AdverseSettings) -> np.ndarray:
        """(B, A) bool: the plan fails future a (contact, TTC or in-path gap below the adverse thresholds), where
        it applies."""
        if self.collision.shape[1] == 1:
            return np.zeros((self.collision.shape[0], 0), dtype=bool)
        ttc = np.minimum(self.min_ttc_s[:, 1:], self.min_rear_ttc_s[:, 1:])
        bad = self.collision[:, 1:] | (ttc < settings.ttc_s) | (self.min_path_gap_m[:, 1:] < settings.min_gap_m)
        return bad & self.applies[:, 1:]

    def predicted_safe(self, ttc_s: float, min_gap_m: float) -> np.ndarray:
        """(B,) bool: the plan passes the reflection's checks against the base prediction (no contact, on
        the road, front and rear TTC >= ``ttc_s``, in-path gap >= ``min_gap_m``; ``SafetyCheck.safe``)."""
        return (~self.collision[:, 0] & ~self.off_road & (self.min_ttc_s[:, 0] >= ttc_s)
                & (self.min_rear_ttc_s[:, 0] >= ttc_s) & (self.min_path_gap_m[:, 0] >= min_gap_m))

    def failed_names(self, settings: AdverseSettings) -> list[str]:
        """Per scenario, the comma-separated adverse futures the plan fails ("" when none)."""
        bad = self.failed(settings)
        adverse = self.names[1:]
        return [",".join(adverse[a] for a in np.flatnonzero(row)) for row in bad]


def check_futures(batch: ScenarioBatch, plan_xy_m: np.ndarray, plan_vxy_mps: np.ndarray, base: NeighbourPrediction,
                  futures: AdverseFutures) -> FutureChecks:
    """Check plans (B, F, 2) against ``base`` and every adverse future, vectorised over (1 + A) x B."""
    b = len(batch)
    k = 1 + len(futures.names)
    rows = np.tile(np.arange(b), k)

    def stacked(first: np.ndarray, rest: np.ndarray) -> np.ndarray:  # (B, ...) + (A, B, ...) -> ((1 + A) B, ...)
        return np.concatenate([np.asarray(first, dtype=rest.dtype)[None], rest]).reshape(k * b, *rest.shape[2:])

    pred = NeighbourPrediction(stacked(base.xy_m, futures.xy_m), stacked(base.vxy_mps, futures.vxy_mps),
                               stacked(base.valid, futures.valid))
    big = batch.take(rows)
    inp = predicted_inputs(big, np.asarray(plan_xy_m, dtype=np.float64)[rows],
                           np.asarray(plan_vxy_mps, dtype=np.float64)[rows], pred)
    chk = check_inputs(big, inp)
    overlap: np.ndarray = np.any(boxes_overlap(inp), axis=1)  # ((1 + A) B, F)
    first = np.where(overlap.any(axis=1), overlap.argmax(axis=1), -1)
    return _future_checks(chk, first, (PREDICTED, *futures.names), futures.applies, k, b)


def _future_checks(chk: SafetyCheck, first_contact_step: np.ndarray, names: tuple[str, ...], applies: np.ndarray,
                   k: int, b: int) -> FutureChecks:
    def cols(a: np.ndarray) -> np.ndarray:
        return np.asarray(a).reshape(k, b).T

    collision = cols(chk.collision).astype(bool)
    step = cols(first_contact_step)
    contact_t = np.where(step >= 0, (step + 1) * DT_S, np.nan)
    return FutureChecks(
        names=names, off_road=np.asarray(chk.off_road, dtype=bool)[:b], collision=collision,
        min_ttc_s=cols(chk.min_ttc_s), min_rear_ttc_s=cols(chk.min_rear_ttc_s),
        min_path_gap_m=cols(chk.min_path_gap_m), contact_time_s=contact_t,
        applies=np.concatenate([np.ones((b, 1), dtype=bool), np.asarray(applies, dtype=bool).T], axis=1),
    )
