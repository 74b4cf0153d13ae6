"""``frenet``: a Werling-style lattice planner (Werling, Ziegler, Kammel, Thrun, ICRA 2010), batched.

The road is straight in the ego frame (s = x, d = y). Every scenario gets the same lattice (``FrenetSampling``):
quintic lateral candidates to lane centres (plus offsets); quartic longitudinal candidates to target speeds,
quintic ones behind the predicted leader of the target lane, and constant braking; each holds its end state to
the 5 s horizon. A pair (i, j) is valid when feasible (``FrenetLimits``) and clear, with margins
(``FrenetSafety``), of the IDM and the cautious prediction. The cheapest valid pair wins (``Lattice.cost``),
else the least unsafe (``Lattice.choose``). Design and calibration: notes/frenet.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from letspi.constants import DT_S, HORIZON_S, N_FUTURE, T0_INDEX
from letspi.keyed import Config
from letspi.metrics.kinematics import off_road
from letspi.metrics.registry import Metric
from letspi.physics.goals import GoalPredictor, KinematicGoalPredictor
from letspi.physics.lanes import lane_centres_m, lane_index_of
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.types import NeighbourPrediction
from letspi.planners.base import PlanBatch
from letspi.planners.config import PREDICTION_OPTIONS, GoalsConfig
from letspi.planners.fitted import FittedFile
from letspi.planners.options import PlannerOption, file_option
from letspi.planners.outputs import output
from letspi.scenario.types import ScenarioBatch

SHIPPED_WEIGHTS_FILE = "frenet_weights.json"
#: lower bound of the speed in the curvature bound [m/s] (the bound is 1 / v²; a standing car cannot steer sideways)
CURVATURE_SPEED_FLOOR_MPS = 0.5
LON_SPEED, LON_FOLLOW, LON_BRAKE = 0, 1, 2
ANY_LANE = -9  # lane code of longitudinal candidates that pair with every lateral candidate
FRENET_WEIGHTS = file_option(
    "frenet_weights_file",
    "Cost weights of the frenet planner (from `letspi fit frenet`; default: the shipped fit)", flag="--frenet-weights")
OPTIONS: tuple[PlannerOption[Any], ...] = (*PREDICTION_OPTIONS, FRENET_WEIGHTS)
OUTPUTS: tuple[Metric, ...] = (
    output("target_lane", "lane", "int64", "lane index the chosen candidate ends in"),
    output("lateral_offset_m", "m", "float64", "lateral offset of the chosen candidate's end from its lane centre"),
    output("lateral_horizon_s", "s", "float64", "duration of the chosen lateral motion"),
    output("lon_mode", "mode", "int64", "longitudinal mode of the chosen candidate: 0 speed, 1 follow, 2 brake"),
    output("target_speed_mps", "m/s", "float64", "end speed of the chosen longitudinal motion"),
    output("lon_horizon_s", "s", "float64", "duration of the chosen longitudinal motion"),
    output("cost", "1", "float64", "the chosen candidate's weighted cost"),
    output("n_safe", "n", "int64", "candidates clear of the predicted neighbours"),
    output("found_safe", "bool", "bool", "some candidate was clear of the predicted neighbours"),
)


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class FrenetWeights(_Frozen):
    """Cost weights (defaults: the fit's starting values), only ratios matter. Per unit of: k_jerk_lon, k_jerk_lat
    ∫ jerk² dt [m²/s⁵]; k_time horizon [s]; k_offset end offset² from the target lane's centre [m²]; k_goal_lane
    lanes from the goal's lane; k_speed (mean speed - v_des)² [(m/s)²]; k_headway, k_rss following deficit [s]."""

    k_jerk_lon: float = Field(default=0.1, ge=0)
    k_jerk_lat: float = Field(default=0.1, ge=0)
    k_time: float = Field(default=0.1, ge=0)
    k_offset: float = Field(default=1.0, ge=0)
    k_goal_lane: float = Field(default=10.0, ge=0)
    k_speed: float = Field(default=1.0, ge=0)
    k_headway: float = Field(default=1.0, ge=0)
    k_rss: float = Field(default=1.0, ge=0)


WEIGHT_NAMES: tuple[str, ...] = tuple(FrenetWeights.model_fields)


class FrenetSampling(_Frozen):
    """The lattice, the same for every scenario."""

    horizons_s: tuple[float, ...] = (3.0, 4.0, 5.0)
    lane_changes: tuple[int, ...] = (0, 1, -1)  # lanes relative to the current one, +1 = left (+y)
    lateral_offsets_m: tuple[float, ...] = (0.0, -0.5, 0.5)
    goal_speed_offsets_mps: tuple[float, ...] = (0.0, -2.0, 2.0)
    current_speed_offsets_mps: tuple[float, ...] = (0.0, -4.0, -8.0, 2.0)
    absolute_speeds_mps: tuple[float, ...] = (0.0,)  # e.g. stopping
    follow_headways_s: tuple[float, ...] = (1.0, 2.0)
    follow_gap_m: float = Field(default=3.0, ge=0)  # > the safety check's front gap
    brake_decels_mps2: tuple[float, ...] = (3.0, 5.0, 8.0)  # constant deceleration from t = 0 to a stop
    #: a braking candidate's acceleration steps at t = 0; its jerk cost is that of a linear ramp over this time
    brake_onset_s: float = Field(default=0.5, gt=0)


class FrenetLimits(_Frozen):
    """Feasibility limits: the metric's success test allows 8 m/s² longitudinal and 4 m/s² lateral."""

    max_accel_mps2: float = Field(default=4.0, gt=0)
    max_decel_mps2: float = Field(default=8.0, gt=0)
    max_lat_accel_mps2: float = Field(default=3.5, gt=0)
    max_curvature_1pm: float = Field(default=0.2, gt=0)
    min_speed_mps: float = -0.1  # below: the candidate drives backwards
    #: candidates start from the t = 0 acceleration, braking at most this hard (3 m/s²: the metric's comfort
    #: bound, beyond which needless braking makes a rear-end contact the ego's fault)
    max_start_decel_mps2: float = Field(default=3.0, gt=0)


class FrenetSafety(_Frozen):
    """Unsafe: a neighbour in the ego's path (lateral overlap plus ``lat_margin_m``) closer bumper to bumper
    than ``front_gap_m`` / ``rear_gap_m`` or than ``ttc_s`` x the closing speed, at any frame."""

    front_gap_m: float = Field(default=2.0, ge=0)
    rear_gap_m: float = Field(default=0.5, ge=0)
    ttc_s: float = Field(default=1.5, ge=0)
    lat_margin_m: float = Field(default=0.3, ge=0)
    cautious_check: bool = True  # check against the cautious prediction too (``_cautious_prediction``)


class FrenetFollowing(_Frozen):
    """Soft following terms (against the cautious prediction), that prediction's settings and the fallback's
    occupied-lane penalty. Desired distance ``standstill_gap_m + desired_headway_s × v_ego``; RSS distance
    (Shalev-Shwartz et al. 2017) ``standstill_gap_m + max(0, v_ego × rss_reaction_s + v_ego² / (2
    rss_ego_decel_mps2) - v_lead² / (2 rss_leader_decel_mps2))``; deficits graded in ``levels`` steps. Without
    a valid pair, a lane change violating margins in its target lane counts ``occupied_lane_change_penalty_s``
    earlier."""

    desired_headway_s: float = Field(default=1.5, ge=0)
    standstill_gap_m: float = Field(default=2.0, ge=0)
    rss_reaction_s: float = Field(default=0.5, ge=0)
    rss_ego_decel_mps2: float = Field(default=4.0, gt=0)
    rss_leader_decel_mps2: float = Field(default=8.0, gt=0)
    levels: int = Field(default=3, ge=1, le=8)
    leader_braking_window_s: float = Field(default=0.4, gt=0, le=2.0)
    leader_braking_min_mps2: float = Field(default=1.0, ge=0)
    leader_braking_max_s: float = Field(default=2.0, gt=0)  # the extrapolated braking lasts at most this long
    occupied_lane_change_penalty_s: float = Field(default=1.0, ge=0)
    #: the following terms are summed over every n-th frame (5: a 0.2 s grid)
    frame_stride: int = Field(default=5, ge=1, le=25)


class FrenetSettings(_Frozen):
    """Everything that changes a ``frenet`` plan besides the goal source and the neighbour prediction."""

    weights: FrenetWeights = Field(default_factory=FrenetWeights)
    sampling: FrenetSampling = Field(default_factory=FrenetSampling)
    limits: FrenetLimits = Field(default_factory=FrenetLimits)
    safety: FrenetSafety = Field(default_factory=FrenetSafety)
    following: FrenetFollowing = Field(default_factory=FrenetFollowing)


class FrenetConfig(Config):
    """``frenet``: the lattice planner's settings (``weights_source``: the weights' file)."""

    cosmetic: ClassVar[frozenset[str]] = frozenset({"weights_source"})

    kind: Literal["frenet"] = "frenet"
    neighbours: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    goals: GoalsConfig
    frenet: FrenetSettings = Field(default_factory=FrenetSettings)
    weights_source: str = "shipped"


FRENET_WEIGHTS_FILE = FittedFile("weights", SHIPPED_WEIGHTS_FILE, "frenet weights file", "letspi fit frenet")


def load_frenet_weights(path: Path | None = None) -> tuple[FrenetWeights, dict[str, Any]]:
    """Weights and the whole record (provenance, objective) from ``path`` (default: the shipped fit)."""
    return FRENET_WEIGHTS_FILE.load(path, lambda values: FrenetWeights(**values))


def save_frenet_weights(path: Path, weights: FrenetWeights, provenance: dict[str, Any],
                        objective: dict[str, Any]) -> Path:
    """Write a fit atomically (``letspi.planners.fitted``)."""
    return FRENET_WEIGHTS_FILE.save(path, weights.model_dump(), provenance, objective)


# Polynomials ------------------------------------------------------------------------------------


def quintic_coefficients(p0: np.ndarray, v0: np.ndarray, a0: np.ndarray, p1: np.ndarray, v1: np.ndarray,
                         a1: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """Coefficients c0..c5 (..., 6) of p(t) = Σ c_k t^k with p, p', p'' = (p0, v0, a0) at 0 and (p1, v1, a1) at T."""
    dp = p1 - p0 - v0 * t_s - 0.5 * a0 * t_s**2
    dv = v1 - v0 - a0 * t_s
    da = a1 - a0
    c3 = (10.0 * dp - 4.0 * dv * t_s + 0.5 * da * t_s**2) / t_s**3
    c4 = (-15.0 * dp + 7.0 * dv * t_s - da * t_s**2) / t_s**4
    c5 = (6.0 * dp - 3.0 * dv * t_s + 0.5 * da * t_s**2) / t_s**5
    return np.stack(np.broadcast_arrays(p0, v0, 0.5 * a0, c3, c4, c5), axis=-1)


def quartic_coefficients(p0: np.ndarray, v0: np.ndarray, a0: np.ndarray, v1: np.ndarray, a1: np.ndarray,
                         t_s: np.ndarray) -> np.ndarray:
    """Coefficients (..., 6) (c5 = 0) of the quartic with (p0, v0, a0) at 0 and p', p'' = (v1, a1) at T."""
    dv = v1 - v0 - a0 * t_s
    da = a1 - a0
    c3 = (3.0 * dv - da * t_s) / (3.0 * t_s**2)
    c4 = (da * t_s - 2.0 * dv) / (4.0 * t_s**3)
    return np.stack(np.broadcast_arrays(p0, v0, 0.5 * a0, c3, c4, np.zeros_like(c4)), axis=-1)


def jerk_integral(c: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """∫_0^T p'''(t)² dt of the polynomials ``c`` (..., 6) over their horizons ``t_s`` (...), exact."""
    c3, c4, c5 = c[..., 3], c[..., 4], c[..., 5]
    t = t_s
    return (36.0 * c3**2 * t + 144.0 * c3 * c4 * t**2 + (240.0 * c3 * c5 + 192.0 * c4**2) * t**3
            + 720.0 * c4 * c5 * t**4 + 720.0 * c5**2 * t**5)


def evaluate_held(c: np.ndarray, horizon_s: np.ndarray, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, speed, acceleration (..., F) of polynomials ``c`` (..., 6) at times ``t_s`` (F,), holding
    the end speed after the horizon (position extrapolated linearly, acceleration 0)."""
    tt = np.minimum(t_s, horizon_s[..., None])
    c0, c1, c2, c3, c4, c5 = (c[..., k, None] for k in range(6))
    p = c0 + tt * (c1 + tt * (c2 + tt * (c3 + tt * (c4 + tt * c5))))
    v = c1 + tt * (2.0 * c2 + tt * (3.0 * c3 + tt * (4.0 * c4 + tt * 5.0 * c5)))
    a = 2.0 * c2 + tt * (6.0 * c3 + tt * (12.0 * c4 + tt * 20.0 * c5))
    beyond = t_s > horizon_s[..., None]
    p = p + v * (t_s - tt)
    a = np.where(beyond, 0.0, a)
    return p, v, a


# The lattice ------------------------------------------------------------------------------------


def _take_rows(record: Any, rows: np.ndarray | slice) -> Any:
    """``record`` with the scenario rows of its per-scenario fields (``SHARED`` fields are per candidate)."""
    return replace(record, **{f.name: getattr(record, f.name)[rows] for f in fields(record)
                              if f.name not in record.SHARED})


def _concat_rows(parts: Sequence[Any]) -> Any:
    """The records of ``parts`` one after another on the scenario axis (``SHARED`` fields from the first)."""
    first = parts[0]
    return replace(first, **{f.name: np.concatenate([getattr(p, f.name) for p in parts], axis=0)
                             for f in fields(first) if f.name not in first.SHARED})


@dataclass(frozen=True)
class Longitudinal:
    """Longitudinal candidates, (B, I) unless said: ``coef`` (B, I, 6), ``horizon_s`` (braking: until the stop),
    ``mode`` (I,) (0 speed, 1 follow, 2 brake), ``lane`` (I,) (the lane change it pairs with, or ``ANY_LANE``),
    ``target_speed_mps``, ``exists``, ``feasible``, ``jerk`` and ``mean_speed_mps`` (cost terms)."""

    SHARED: ClassVar[tuple[str, ...]] = ("mode", "lane")
    coef: np.ndarray
    horizon_s: np.ndarray
    mode: np.ndarray
    lane: np.ndarray
    target_speed_mps: np.ndarray
    exists: np.ndarray
    feasible: np.ndarray
    jerk: np.ndarray
    mean_speed_mps: np.ndarray


@dataclass(frozen=True)
class Lateral:
    """Lateral candidates, (B, J) unless said: ``coef`` (B, J, 6), ``horizon_s``, ``lane`` and ``offset_m``
    (J,), ``target_y_m``, ``exists``, ``feasible``, ``jerk`` and ``lanes_from_goal`` (cost terms)."""

    SHARED: ClassVar[tuple[str, ...]] = ("horizon_s", "lane", "offset_m")
    coef: np.ndarray
    horizon_s: np.ndarray
    lane: np.ndarray
    offset_m: np.ndarray
    target_y_m: np.ndarray
    exists: np.ndarray
    feasible: np.ndarray
    jerk: np.ndarray
    lanes_from_goal: np.ndarray


@dataclass(frozen=True)
class Pairs:
    """Every (longitudinal, lateral) pair, (B, I, J): ``ok`` (both exist, lanes match), ``feasible``,
    ``contact`` / ``violation`` scores (0 = none, ``_pair_checks``), ``occupied``, ``unsafe_rank`` (the
    fallback's first key), following deficits [s]."""

    SHARED: ClassVar[tuple[str, ...]] = ()
    ok: np.ndarray
    feasible: np.ndarray
    contact: np.ndarray
    violation: np.ndarray
    occupied: np.ndarray
    unsafe_rank: np.ndarray
    headway_deficit_s: np.ndarray
    rss_deficit_s: np.ndarray


@dataclass(frozen=True)
class Lattice:
    """Weight-independent part of the planner for B scenarios: candidates, their checks and cost terms;
    ``v_des_mps`` (B,), ``goals_xy_m`` (B, 2)."""

    lon: Longitudinal
    lat: Lateral
    pairs: Pairs
    v_des_mps: np.ndarray
    goals_xy_m: np.ndarray

    def __len__(self) -> int:
        return int(self.v_des_mps.shape[0])

    @property
    def valid(self) -> np.ndarray:
        """(B, I, J) bool: existing, feasible and clear of every predicted neighbour with margins."""
        out: np.ndarray = self.pairs.ok & self.pairs.feasible & (self.pairs.violation == 0)
        return out

    def cost(self, w: FrenetWeights) -> np.ndarray:
        """(B, I, J) cost of every pair (``FrenetWeights`` terms); inf for pairs that do not exist."""
        lo, la, pr = self.lon, self.lat, self.pairs
        lon = (w.k_jerk_lon * lo.jerk + w.k_time * lo.horizon_s
               + w.k_speed * (lo.mean_speed_mps - self.v_des_mps[:, None]) ** 2)
        lat = (w.k_jerk_lat * la.jerk + w.k_time * la.horizon_s[None, :]
               + w.k_offset * la.offset_m[None, :] ** 2 + w.k_goal_lane * la.lanes_from_goal)
        total = (lon[:, :, None] + lat[:, None, :] + w.k_headway * pr.headway_deficit_s
                 + w.k_rss * pr.rss_deficit_s)
        return np.where(pr.ok, total, np.inf)

    def choose(self, w: FrenetWeights) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Chosen (i, j) per scenario, (B,) each, with its cost and the number of valid pairs: the cheapest valid
        pair, else the least unsafe: latest first contact (a lane change into an occupied lane counts earlier),
        fewest contacts, then feasible, fewest margin violations, cost."""
        pr = self.pairs
        b, _, n_j = pr.ok.shape
        cost = self.cost(w).reshape(b, -1)
        valid = self.valid.reshape(b, -1)
        n_valid = valid.sum(axis=1)
        best_valid = np.argmin(np.where(valid, cost, np.inf), axis=1)
        pick = pr.ok.reshape(b, -1).copy()
        for key in (pr.unsafe_rank.reshape(b, -1), ~pr.feasible.reshape(b, -1), pr.violation.reshape(b, -1)):
            k = np.where(pick, key.astype(np.float64), np.inf)
            pick &= k <= k.min(axis=1, keepdims=True)
        best_unsafe = np.argmin(np.where(pick, cost, np.inf), axis=1)
        flat = np.where(n_valid > 0, best_valid, best_unsafe)
        chosen_cost = np.take_along_axis(cost, flat[:, None], axis=1)[:, 0]
        return flat // n_j, flat % n_j, chosen_cost, n_valid

    def plans(self, i: np.ndarray, j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities (B, F, 2) of pair (i[b], j[b]) of every scenario, t = dt .. F dt."""
        rows = np.arange(len(self))
        t_s = np.arange(1, N_FUTURE + 1) * DT_S
        x, vx, _ = evaluate_held(self.lon.coef[rows, i], self.lon.horizon_s[rows, i], t_s)
        y, vy, _ = evaluate_held(self.lat.coef[rows, j], self.lat.horizon_s[j], t_s)
        return np.stack([x, y], axis=-1), np.stack([vx, vy], axis=-1)

    def take(self, index: np.ndarray | slice) -> Lattice:
        """The lattice of scenarios ``index`` (candidate-axis arrays are shared)."""
        return Lattice(_take_rows(self.lon, index), _take_rows(self.lat, index), _take_rows(self.pairs, index),
                       self.v_des_mps[index], self.goals_xy_m[index])

    @staticmethod
    def concat(parts: Sequence[Lattice]) -> Lattice:
        """The lattices of ``parts`` one after another on the scenario axis."""
        return Lattice(_concat_rows([p.lon for p in parts]), _concat_rows([p.lat for p in parts]),
                       _concat_rows([p.pairs for p in parts]), np.concatenate([p.v_des_mps for p in parts]),
                       np.concatenate([p.goals_xy_m for p in parts]))


def _lon_grid(s: FrenetSampling) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per longitudinal candidate (I,): horizon (braking: a 5 s placeholder), mode, lane change, and (I, 2) a
    parameter with its kind (0 goal speed, 1 current speed, 2 following, 3 absolute speed, 4 braking)."""
    rows: list[tuple[float, int, int, float, int]] = []  # horizon, mode, lane, value, kind
    for t in s.horizons_s:
        rows += [(t, LON_SPEED, ANY_LANE, d, 0) for d in s.goal_speed_offsets_mps]
        rows += [(t, LON_SPEED, ANY_LANE, d, 1) for d in s.current_speed_offsets_mps]
        rows += [(t, LON_SPEED, ANY_LANE, v, 3) for v in s.absolute_speeds_mps]
    rows += [(HORIZON_S, LON_BRAKE, ANY_LANE, d, 4) for d in s.brake_decels_mps2]
    for lane in s.lane_changes:
        for t in s.horizons_s:
            rows += [(t, LON_FOLLOW, lane, h, 2) for h in s.follow_headways_s]
    arr = np.array(rows, dtype=np.float64)
    return arr[:, 0], arr[:, 1].astype(np.int64), arr[:, 2].astype(np.int64), arr[:, 3:5]


def _lat_grid(s: FrenetSampling) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per lateral candidate: horizon, lane change, offset, (J,) each."""
    mesh = np.meshgrid(np.array(s.lane_changes, dtype=np.float64), np.array(s.lateral_offsets_m),
                       np.array(s.horizons_s), indexing="ij")
    lane, off, t = (m.reshape(-1) for m in mesh)
    return t, lane.astype(np.int64), off


def _goal_terms(batch: ScenarioBatch, goals_xy_m: np.ndarray, x0: np.ndarray, v0: np.ndarray,
                cur: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Goal progress over the horizon [m], desired speed [m/s] and the goal's lane index, (B,) each
    (no goal: constant speed in the current lane)."""
    g = np.asarray(goals_xy_m, dtype=np.float64)
    progress = np.where(np.isfinite(g[:, 0]), g[:, 0] - x0, v0 * HORIZON_S)
    progress = np.maximum(progress, 0.0)
    idx = lane_index_of(np.nan_to_num(g[:, 1]), batch.marking_y_m)
    goal_lane = np.where((idx >= 0) & np.isfinite(g[:, 1]), idx, cur)
    return progress, progress / HORIZON_S, goal_lane


def _leaders(batch: ScenarioBatch, pred: NeighbourPrediction, x0: np.ndarray, lanes: np.ndarray,
             lane_exists: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Slot of the closest visible neighbour ahead in each target lane at t = 0, (B, L) (-1 none), and
    whether its prediction stays valid to the end, (B, L)."""
    xy0 = batch.nbr_xy_m[:, :, T0_INDEX].astype(np.float64)
    seen = batch.nbr_valid[:, :, T0_INDEX] & np.isfinite(xy0).all(axis=-1) & pred.valid[:, :, 0]
    nbr_lane = np.where(seen, lane_index_of_many(np.nan_to_num(xy0[..., 1]), batch.marking_y_m), -2)
    ahead = seen & (np.nan_to_num(xy0[..., 0]) > x0[:, None])
    match = ahead[:, None, :] & (nbr_lane[:, None, :] == lanes[:, :, None]) & lane_exists[:, :, None]  # (B, L, N)
    dist = np.where(match, np.nan_to_num(xy0[..., 0])[:, None, :], np.inf)
    slot = np.argmin(dist, axis=2)
    has = np.isfinite(np.min(dist, axis=2))
    return np.where(has, slot, -1), has


def lane_index_of_many(y_m: np.ndarray, marking_y_m: np.ndarray) -> np.ndarray:
    """``lane_index_of`` for (B, N) positions: lane index (clipped onto the road), -1 without lanes."""
    b, n = y_m.shape
    return lane_index_of(y_m.reshape(-1), np.repeat(np.asarray(marking_y_m), n, axis=0)).reshape(b, n)


def build_lattice(batch: ScenarioBatch, pred: NeighbourPrediction, goals_xy_m: np.ndarray,
                  settings: FrenetSettings, chunk_size: int = 32) -> Lattice:
    """The weight-independent lattice of ``batch`` (history suffices) against predicted neighbours ``pred``."""
    if len(batch) > chunk_size:
        parts = (slice(k, k + chunk_size) for k in range(0, len(batch), chunk_size))
        return Lattice.concat([build_lattice(batch.take(s), pred.take(s), goals_xy_m[s], settings, chunk_size)
                               for s in parts])
    return _build_chunk(batch, pred, np.asarray(goals_xy_m, dtype=np.float64), settings)


@dataclass(frozen=True)
class _Start:
    """The t = 0 state and road of a chunk, (B,) arrays (``_build_chunk``)."""

    x0: np.ndarray
    y0: np.ndarray
    vx0: np.ndarray
    vy0: np.ndarray
    ax0: np.ndarray
    ay0: np.ndarray
    marks: np.ndarray
    centres: np.ndarray
    n_lanes: np.ndarray
    cur: np.ndarray
    progress: np.ndarray
    v_des: np.ndarray
    goal_lane: np.ndarray


def _start(batch: ScenarioBatch, goals_xy_m: np.ndarray, lim: FrenetLimits) -> _Start:
    x0, y0 = (np.nan_to_num(batch.ego_xy0_m[:, k].astype(np.float64)) for k in (0, 1))
    vx0 = np.maximum(np.nan_to_num(batch.ego_vxy0_mps[:, 0].astype(np.float64)), 0.0)
    # the recorded/simulated acceleration at t = 0, within the limits (a candidate cannot start infeasible)
    a_now = np.nan_to_num(batch.ego_axy_mps2[:, T0_INDEX].astype(np.float64))
    marks = batch.marking_y_m.astype(np.float64)
    centres = lane_centres_m(marks)  # (B, M - 1)
    cur = lane_index_of(y0, marks)  # (B,), -1 without lanes
    progress, v_des, goal_lane = _goal_terms(batch, goals_xy_m, x0, vx0, cur)
    return _Start(x0=x0, y0=y0, vx0=vx0, vy0=np.nan_to_num(batch.ego_vxy0_mps[:, 1].astype(np.float64)),
                  ax0=np.clip(a_now[:, 0], -min(lim.max_start_decel_mps2, lim.max_decel_mps2), lim.max_accel_mps2),
                  ay0=np.clip(a_now[:, 1], -lim.max_lat_accel_mps2, lim.max_lat_accel_mps2), marks=marks,
                  centres=centres, n_lanes=np.isfinite(centres).sum(axis=1), cur=cur, progress=progress, v_des=v_des,
                  goal_lane=goal_lane)


def _lateral(batch: ScenarioBatch, st: _Start, s: FrenetSampling, lim: FrenetLimits, t_s: np.ndarray,
             ) -> tuple[Lateral, _LateralPaths]:
    """Lateral candidates (B, J) and what the pair checks need of their trajectories."""
    b = len(batch)
    lat_t, lat_lane, lat_off = _lat_grid(s)
    target_idx = st.cur[:, None] + lat_lane[None, :]
    if st.centres.shape[1]:
        lane_ok = (target_idx >= 0) & (target_idx < st.n_lanes[:, None]) & (st.cur[:, None] >= 0)
        lane_y = np.take_along_axis(np.nan_to_num(st.centres, nan=0.0),
                                    np.clip(target_idx, 0, st.centres.shape[1] - 1), axis=1)
    else:
        lane_ok = np.zeros(target_idx.shape, dtype=bool)
        lane_y = np.zeros(target_idx.shape)
    no_lanes = (st.n_lanes == 0)[:, None] & (lat_lane[None, :] == 0)
    exists = lane_ok | no_lanes
    y1 = np.where(no_lanes, st.y0[:, None], lane_y) + lat_off[None, :]
    zeros = np.zeros_like(y1)
    coef = quintic_coefficients(st.y0[:, None], st.vy0[:, None], st.ay0[:, None], y1, zeros, zeros, lat_t[None, :])
    y, vy, ay = evaluate_held(coef, np.broadcast_to(lat_t, y1.shape), t_s)  # (B, J, F)
    leaves_road = off_road(y.reshape(-1, N_FUTURE), np.repeat(batch.ego_width_m.astype(np.float64), len(lat_t)),
                           np.repeat(st.marks, len(lat_t), axis=0),
                           np.repeat(batch.marking_is_edge, len(lat_t), axis=0)).reshape(b, -1)
    peak_ay = np.abs(ay).max(axis=2)
    lateral = Lateral(coef=coef, horizon_s=lat_t, lane=lat_lane, offset_m=lat_off, target_y_m=y1, exists=exists,
                      feasible=exists & ~leaves_road & (peak_ay <= lim.max_lat_accel_mps2),
                      jerk=jerk_integral(coef, lat_t[None, :]),
                      lanes_from_goal=np.abs(target_idx - st.goal_lane[:, None]).astype(np.float64))
    return lateral, _LateralPaths(y=y, peak_ay=peak_ay, peak_vy=np.abs(vy).max(axis=2), target_lane=target_idx)


def _longitudinal(batch: ScenarioBatch, pred: NeighbourPrediction, st: _Start, s: FrenetSampling,
                  lim: FrenetLimits, t_s: np.ndarray) -> tuple[Longitudinal, _LongitudinalPaths]:
    """Longitudinal candidates (B, I) and what the pair checks need of their trajectories."""
    b = len(batch)
    lon_t, lon_mode, lon_lane, lon_par = _lon_grid(s)
    value, kind = lon_par[:, 0], lon_par[:, 1]
    tt = lon_t[None, :]
    x0, vx0, ax0 = st.x0[:, None], st.vx0[:, None], st.ax0[:, None]
    # end speed that reaches the goal's progress at 5 s when held after T (quartic, a = 0 at T)
    v_goal = (st.progress[:, None] - vx0 * tt / 2.0 - ax0 * tt**2 / 12.0) / (HORIZON_S - tt / 2.0)
    base = np.where(kind[None, :] == 0, v_goal, np.where(kind[None, :] == 1, vx0, 0.0))
    v_speed = np.maximum(base + value[None, :], 0.0)
    follow = lon_mode == LON_FOLLOW
    # following: the predicted leader of the candidate's lane
    lanes_abs = st.cur[:, None] + np.array(s.lane_changes, dtype=np.int64)[None, :]  # (B, L)
    lanes_exist = (lanes_abs >= 0) & (lanes_abs < st.n_lanes[:, None]) & (st.cur[:, None] >= 0)
    leader, has_leader = _leaders(batch, pred, st.x0, lanes_abs, lanes_exist)  # (B, L)
    lane_pos = np.array([list(s.lane_changes).index(int(c)) if c != ANY_LANE else 0 for c in lon_lane])
    k_t = np.clip(np.round(lon_t / DT_S).astype(np.int64) - 1, 0, N_FUTURE - 1)  # frame of t = T
    rows = np.arange(b)[:, None]
    slot = np.maximum(leader[:, lane_pos], 0)  # (B, I)
    lead_x = pred.xy_m[rows, slot, k_t[None, :], 0]
    lead_v = np.maximum(pred.vxy_mps[rows, slot, k_t[None, :], 0], 0.0)
    lead_ok = has_leader[:, lane_pos] & pred.valid[rows, slot, k_t[None, :]]
    half_len = 0.5 * (batch.ego_length_m.astype(np.float64)[:, None]
                      + np.nan_to_num(batch.nbr_length_m.astype(np.float64))[rows, slot])
    s1 = lead_x - half_len - s.follow_gap_m - value[None, :] * lead_v
    zeros = np.zeros((b, len(lon_t)))
    coef_speed = quartic_coefficients(x0, vx0, ax0, v_speed, zeros, tt)
    coef_follow = quintic_coefficients(x0, vx0, ax0, s1, lead_v, zeros, tt)
    # braking: x0 + v0 t - d t² / 2 to a stop (or to 5 s), then held; no jerk after the step at t = 0, which
    # is priced as a linear ramp from a0 to -d over brake_onset_s (else braking would be free of jerk cost)
    brake = lon_mode == LON_BRAKE
    decel = np.where(brake, value, 1.0)[None, :]
    horizon = np.where(brake[None, :], np.minimum(vx0 / decel, HORIZON_S), tt)  # (B, I)
    onset_jerk = np.where(brake[None, :], (ax0 + decel) ** 2 / s.brake_onset_s, 0.0)
    coef_brake = np.stack(np.broadcast_arrays(x0, vx0, -0.5 * decel, zeros, zeros, zeros), axis=-1)
    coef = np.where(follow[None, :, None], coef_follow, np.where(brake[None, :, None], coef_brake, coef_speed))
    exists = np.where(follow[None, :], lead_ok, True)
    x, vx, ax = evaluate_held(coef, horizon, t_s)  # (B, I, F)
    feasible = (exists & (ax.max(axis=2) <= lim.max_accel_mps2 + 1e-9)
                & (ax.min(axis=2) >= -lim.max_decel_mps2 - 1e-9) & (vx.min(axis=2) >= lim.min_speed_mps))
    target = np.where(follow[None, :], lead_v, np.where(brake[None, :], vx[:, :, -1], v_speed))
    longitudinal = Longitudinal(coef=coef, horizon_s=horizon, mode=lon_mode, lane=lon_lane, target_speed_mps=target,
                                exists=exists, feasible=feasible, jerk=jerk_integral(coef, horizon) + onset_jerk,
                                mean_speed_mps=(x[:, :, -1] - st.x0[:, None]) / HORIZON_S)
    return longitudinal, _LongitudinalPaths(x=x, vx=vx, v_min=vx.min(axis=2), peak_ax=np.abs(ax).max(axis=2))


@dataclass(frozen=True)
class _LateralPaths:
    """What the pair checks read of the lateral candidates: ``y`` (B, J, F), peaks (B, J), target lanes (B, J)."""

    y: np.ndarray
    peak_ay: np.ndarray
    peak_vy: np.ndarray
    target_lane: np.ndarray


@dataclass(frozen=True)
class _LongitudinalPaths:
    """What the pair checks read of the longitudinal candidates: ``x``, ``vx`` (B, I, F); peaks (B, I)."""

    x: np.ndarray
    vx: np.ndarray
    v_min: np.ndarray
    peak_ax: np.ndarray


def _build_chunk(batch: ScenarioBatch, pred: NeighbourPrediction, goals_xy_m: np.ndarray,
                 settings: FrenetSettings) -> Lattice:
    s, lim = settings.sampling, settings.limits
    t_s = np.arange(1, N_FUTURE + 1) * DT_S  # (F,)
    st = _start(batch, goals_xy_m, lim)
    lat, lat_paths = _lateral(batch, st, s, lim, t_s)
    lon, lon_paths = _longitudinal(batch, pred, st, s, lim, t_s)
    # pairs: which exist, the curvature bound |κ| <= (|ay| |vx| + |vy| |ax|) / vx³ with separable maxima
    pairs_lane = (lon.lane[:, None] == ANY_LANE) | (lon.lane[:, None] == lat.lane[None, :])  # (I, J)
    pair_ok = pairs_lane[None] & lon.exists[:, :, None] & lat.exists[:, None, :]
    v_min = np.maximum(lon_paths.v_min, CURVATURE_SPEED_FLOOR_MPS)[:, :, None]
    kappa = (lat_paths.peak_ay[:, None, :] / v_min**2
             + lat_paths.peak_vy[:, None, :] * lon_paths.peak_ax[:, :, None] / v_min**3)
    feasible = lon.feasible[:, :, None] & lat.feasible[:, None, :] & (kappa <= lim.max_curvature_1pm)
    checks = _pair_checks(batch, pred, lon_paths.x, lon_paths.vx, lat_paths.y, lat_paths.target_lane, lat.lane != 0,
                          settings)
    pairs = Pairs(ok=pair_ok, feasible=feasible, contact=checks.contact, violation=checks.violation,
                  occupied=checks.occupied, unsafe_rank=checks.unsafe_rank,
                  headway_deficit_s=checks.headway_deficit_s, rss_deficit_s=checks.rss_deficit_s)
    return Lattice(lon, lat, pairs, st.v_des, np.asarray(goals_xy_m, dtype=np.float64))


@dataclass(frozen=True)
class _PairChecks:
    """Per pair (B, I, J) (``Lattice``): contact, violation, unsafe_rank (int64 scores), occupied (bool),
    headway_deficit_s and rss_deficit_s (float64)."""

    contact: np.ndarray
    violation: np.ndarray
    occupied: np.ndarray
    unsafe_rank: np.ndarray
    headway_deficit_s: np.ndarray
    rss_deficit_s: np.ndarray


def _cautious_prediction(batch: ScenarioBatch, pred: NeighbourPrediction, fol: FrenetFollowing,
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Neighbour x and vx (B, F, N): the IDM prediction or, where further back, the t = 0 state extrapolated with a
    deceleration over ``leader_braking_min_mps2`` (mean over the last ``leader_braking_window_s``) kept until the
    stop or for ``leader_braking_max_s``, then the speed."""
    k = max(1, round(fol.leader_braking_window_s / DT_S))
    v_now = batch.nbr_vxy_mps[:, :, T0_INDEX, 0].astype(np.float64)
    v_then = batch.nbr_vxy_mps[:, :, T0_INDEX - k, 0].astype(np.float64)
    seen = (batch.nbr_valid[:, :, T0_INDEX] & batch.nbr_valid[:, :, T0_INDEX - k] & np.isfinite(v_now)
            & np.isfinite(v_then))
    accel = np.where(seen, (np.nan_to_num(v_now) - np.nan_to_num(v_then)) / (k * DT_S), 0.0)
    decel = np.where(accel < -fol.leader_braking_min_mps2, -accel, 0.0)[..., None]  # (B, N, 1)
    v0 = np.maximum(np.nan_to_num(v_now), 0.0)[..., None]
    t_s = np.arange(1, N_FUTURE + 1) * DT_S
    t_brake = np.minimum(t_s, np.minimum(v0 / np.maximum(decel, 1e-9), fol.leader_braking_max_s))  # (B, N, F)
    v_ext = v0 - decel * t_brake
    x_ext = (np.nan_to_num(batch.nbr_xy_m[:, :, T0_INDEX, 0].astype(np.float64))[..., None]
             + t_brake * (v0 - 0.5 * decel * t_brake) + v_ext * (t_s - t_brake))
    x_idm, v_idm = pred.xy_m[..., 0], pred.vxy_mps[..., 0]
    now = batch.nbr_valid[:, :, T0_INDEX] & np.isfinite(batch.nbr_xy_m[:, :, T0_INDEX, 0]) & np.isfinite(v_now)
    use = now[..., None] & (x_ext < x_idm)  # a neighbour unseen at t = 0 keeps its IDM prediction
    x = np.where(use, x_ext, x_idm)
    v = np.where(use, v_ext, v_idm)
    return x.transpose(0, 2, 1), v.transpose(0, 2, 1)


def _pair_checks(batch: ScenarioBatch, pred: NeighbourPrediction, x: np.ndarray, vx: np.ndarray, y: np.ndarray,
                 target_lane: np.ndarray, lane_change: np.ndarray, settings: FrenetSettings) -> _PairChecks:
    """Safety check and following terms of every pair; x, vx (B, I, F), y (B, J, F), target_lane (B, J),
    lane_change (J,). Pair (i, j) overlaps neighbour n at frame f iff i does longitudinally and j laterally: one
    AND of 64-bit words of per-candidate flags. Score = (W - first word with an overlap) x 1e6 + overlapping
    (neighbour, frame) pairs. Following deficit ≈ ∫ Σ_n max(0, 1 - gap / distance) dt [s], in ``levels`` steps."""
    safety, fol = settings.safety, settings.following
    f32 = np.float32
    valid = (pred.valid & np.isfinite(pred.xy_m).all(axis=-1)).transpose(0, 2, 1)[:, None]  # (B, 1, F, N)
    xn = pred.xy_m[..., 0].astype(f32).transpose(0, 2, 1)[:, None]
    yn = pred.xy_m[..., 1].astype(f32).transpose(0, 2, 1)[:, None]
    vn = pred.vxy_mps[..., 0].astype(f32).transpose(0, 2, 1)[:, None]
    half_len = (0.5 * (batch.ego_length_m[:, None] + np.nan_to_num(batch.nbr_length_m))).astype(f32)
    half_wid = (0.5 * (batch.ego_width_m[:, None] + np.nan_to_num(batch.nbr_width_m))).astype(f32)
    half_len = half_len[:, None, None, :]  # (B, 1, 1, N)
    half_wid = half_wid[:, None, None, :]

    xe = x.astype(f32)[..., None]  # (B, I, F, 1)
    ve = vx.astype(f32)[..., None]
    xl, vl = (a.astype(f32)[:, None] for a in _cautious_prediction(batch, pred, fol))  # (B, 1, F, N)

    hl = half_len
    front_reach, rear_reach = hl + f32(safety.front_gap_m), -hl - f32(safety.rear_gap_m)

    def lon_flags(x_nbr: np.ndarray, v_nbr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Contact and margin flags (B, I, F, N), unmasked; ahead: dx < hl + front_gap or u < hl with
        u = dx - ttc x closing speed (one pass fewer than a max); behind likewise."""
        dx = x_nbr - xe  # (B, I, F, N), > 0: the neighbour is ahead
        u = dx - f32(safety.ttc_s) * (ve - v_nbr)  # ve - v_nbr > 0: closing on a vehicle ahead
        ahead_ok = (dx < front_reach) | (u < hl)
        behind_ok = (dx > rear_reach) | (u > -hl)
        return np.abs(dx) < hl, ahead_ok & behind_ok

    contact_flags, margin_flags = lon_flags(xn, vn)
    if safety.cautious_check:  # a pair is unsafe when it is under either prediction
        cautious_contact, cautious_margin = lon_flags(xl, vl)
        contact_flags |= cautious_contact
        margin_flags |= cautious_margin
    contact_flags &= valid
    margin_flags &= valid
    lon_contact, lon_margin = _bits(contact_flags), _bits(margin_flags)
    dy = np.abs(yn - y.astype(f32)[..., None])  # (B, J, F, N)
    lat_margin_flags = dy < half_wid + f32(safety.lat_margin_m)
    lat_margin = _bits(lat_margin_flags)
    contact = _and_score(lon_contact, _bits(dy < half_wid))
    violation = _and_score(lon_margin, lat_margin)

    # occupied target lane: the margin violations of a lane change with the neighbours in its target lane
    nbr_lane = lane_index_of_many(np.nan_to_num(pred.xy_m[..., 1]).transpose(0, 2, 1).reshape(len(batch), -1),
                                  batch.marking_y_m).reshape(valid.shape[0], 1, *valid.shape[2:])  # (B, 1, F, N)
    in_target = (nbr_lane == target_lane[:, :, None, None]) & lane_change[None, :, None, None]
    occupied = _and_any(lon_margin, _bits(lat_margin_flags & in_target))
    words_s = DT_S * 64.0 / valid.shape[3]  # frames per 64-bit word x dt
    penalty = round(fol.occupied_lane_change_penalty_s / words_s) * 1_000_000
    unsafe_rank = contact + np.where(occupied, penalty, 0)

    # following terms, against the cautious prediction, on every ``frame_stride``-th frame (gaps change slowly)
    sub = slice(fol.frame_stride - 1, None, fol.frame_stride)
    xe_s, ve_s, xl_s, vl_s = xe[:, :, sub], ve[:, :, sub], xl[:, :, sub], vl[:, :, sub]
    lat_margin_s = _bits(lat_margin_flags[:, :, sub])
    gap = xl_s - xe_s - half_len  # bumper to bumper, (B, I, F', N)
    ahead = (xl_s > xe_s) & valid[:, :, sub]
    speed = np.maximum(ve_s, f32(0.0))
    desired = f32(fol.standstill_gap_m) + f32(fol.desired_headway_s) * speed  # (B, I, F', 1)
    rss = f32(fol.standstill_gap_m) + np.maximum(
        speed * f32(fol.rss_reaction_s) + speed**2 / f32(2.0 * fol.rss_ego_decel_mps2)
        - np.maximum(vl_s, f32(0.0))**2 / f32(2.0 * fol.rss_leader_decel_mps2), f32(0.0))  # (B, I, F', N)
    never = f32(np.inf)
    ratio_desired = np.where(ahead, gap / desired, never)
    ratio_rss = np.where(ahead, gap / rss, never)
    headway = np.zeros(contact.shape, dtype=np.int64)
    rss_count = np.zeros(contact.shape, dtype=np.int64)
    for k in range(1, fol.levels + 1):  # K <= 8 levels, each one AND per pair
        level = f32(k / fol.levels)
        headway += _and_count(_bits(ratio_desired < level), lat_margin_s)
        rss_count += _and_count(_bits(ratio_rss < level), lat_margin_s)
    scale = DT_S * fol.frame_stride / fol.levels
    return _PairChecks(contact=contact, violation=violation, occupied=occupied, unsafe_rank=unsafe_rank,
                       headway_deficit_s=headway * scale, rss_deficit_s=rss_count * scale)


def _bits(flags: np.ndarray) -> np.ndarray:
    """(B, K, F, N) bool -> (B, K, W) uint64 bit strings (frame-major, zero padded; 64 / N frames per word)."""
    b, k = flags.shape[:2]
    packed = np.packbits(flags.reshape(b, k, -1), axis=-1)  # (B, K, ceil(F N / 8)) bytes
    pad = (-packed.shape[2]) % 8
    if pad:
        packed = np.concatenate([packed, np.zeros((b, k, pad), dtype=np.uint8)], axis=2)
    return np.ascontiguousarray(packed).view(np.uint64)


def _and_count(lon_bits: np.ndarray, lat_bits: np.ndarray) -> np.ndarray:
    """Number of common set bits (B, I, J) of every pair of (B, I, W) and (B, J, W) bit strings."""
    out: np.ndarray = np.bitwise_count(lon_bits[:, :, None, :] & lat_bits[:, None, :, :]).sum(axis=3,
                                                                                             dtype=np.int64)
    return out


def _and_any(lon_bits: np.ndarray, lat_bits: np.ndarray) -> np.ndarray:
    """Whether every pair of (B, I, W) and (B, J, W) bit strings has a common set bit, (B, I, J)."""
    out: np.ndarray = ((lon_bits[:, :, None, :] & lat_bits[:, None, :, :]) != 0).any(axis=3)
    return out


def _and_score(lon_bits: np.ndarray, lat_bits: np.ndarray) -> np.ndarray:
    """Scores (B, I, J) of the pairwise ANDs of (B, I, W) and (B, J, W) bit strings (``_pair_checks``)."""
    both = lon_bits[:, :, None, :] & lat_bits[:, None, :, :]  # (B, I, J, W)
    hit = both != 0
    n_words = both.shape[3]
    count = np.bitwise_count(both).sum(axis=3, dtype=np.int64)
    first = np.where(hit.any(axis=3), hit.argmax(axis=3), n_words)
    out: np.ndarray = (n_words - first).astype(np.int64) * 1_000_000 + count
    return out


# The planner ------------------------------------------------------------------------------------


def shipped_settings() -> FrenetSettings:
    """The default lattice with the shipped (fitted) weights."""
    return FrenetSettings(weights=load_frenet_weights()[0])


@dataclass
class FrenetPlanner:
    """Planner ``frenet`` (shipped weights by default); ``info``: ``OUTPUTS`` of the chosen pair."""

    settings: FrenetSettings = field(default_factory=shipped_settings)
    goal_predictor: GoalPredictor = field(default_factory=KinematicGoalPredictor)
    neighbour_mode: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    name: str = "frenet"
    batch_size: int = 1024

    def lattice(self, batch: ScenarioBatch) -> Lattice:
        goals = self.goal_predictor.predict_goals(batch).top
        return build_lattice(batch, predict_neighbours(batch, self.neighbour_mode), goals, self.settings)

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        return plan_from_lattice(self.lattice(batch), self.settings.weights)


def plan_from_lattice(lattice: Lattice, weights: FrenetWeights) -> PlanBatch:
    """Choose with ``weights`` and return the plans with their ``info``."""
    i, j, cost, n_valid = lattice.choose(weights)
    xy, vxy = lattice.plans(i, j)
    rows = np.arange(len(lattice))
    lat, lon = lattice.lat, lattice.lon
    info = {"target_lane": lat.lane[j].astype(np.int64), "lateral_offset_m": lat.offset_m[j],
            "lateral_horizon_s": lat.horizon_s[j], "lon_mode": lon.mode[i].astype(np.int64),
            "target_speed_mps": lon.target_speed_mps[rows, i], "lon_horizon_s": lon.horizon_s[rows, i],
            "cost": cost, "n_safe": n_valid.astype(np.int64), "found_safe": n_valid > 0}
    return PlanBatch(xy_m=xy, vxy_mps=vxy, goals_xy_m=lattice.goals_xy_m.copy(), info=info)
