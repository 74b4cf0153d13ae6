"""``frenet``: a Werling-style lattice planner (Werling, Ziegler, Kammel, Thrun, ICRA 2010), batched.

The road is straight in the ego frame, so the Frenet coordinates are the scenario's own: s = x
(along the carriageway) and d = y (to the left). Every scenario gets the same candidate lattice:

* **lateral** (index j): quintic polynomials y(t) from the t = 0 state (y, vy, ay) to a target
  y_T = lane centre + offset with vy = ay = 0 at T, for the current lane and the lanes left and
  right of it (where they exist), ``lateral_offsets_m`` inside the lane, horizons ``horizons_s``;
* **longitudinal** (index i):
  - velocity keeping: quartic polynomials x(t) from (x, vx, ax) to a target speed with ax = 0 at T:
    the speed that reaches the goal's progress at 5 s with this horizon plus ``goal_speed_offsets_mps``,
    and the current speed plus ``current_speed_offsets_mps``;
  - following: quintic polynomials to a point ``follow_gap_m + headway x v_leader`` behind the
    *predicted* leader of a target lane (the closest neighbour ahead in that lane at t = 0) at T,
    at the leader's predicted speed, ax = 0; paired only with lateral candidates into that lane;
* after its horizon a candidate holds its end state (constant speed, constant y) up to the
  planning horizon of 5 s (125 frames at 25 Hz), so all candidates are judged over the same 5 s.

Candidates are the pairs (i, j). Cost (Werling's terms; weights in ``FrenetWeights``)::

    k_jerk_lon ∫ x'''² dt + k_jerk_lat ∫ y'''² dt + k_time (T_lon + T_lat)
    + k_offset (y_T - centre of the target lane)² + k_goal_lane |target lane - goal lane|
    + k_speed (mean speed over 5 s - v_des)²

with the goal (from the goal predictor, as ``sf`` and ``gnp`` use it) giving the preferred lane (the
goal's lane) and the desired speed ``v_des`` = goal progress / 5 s.

Rejected (not *valid*):

* infeasible: longitudinal acceleration outside [-``max_decel_mps2``, ``max_accel_mps2``], backwards
  motion, lateral acceleration above ``max_lat_accel_mps2``, a curvature bound above
  ``max_curvature_1pm``, the ego box beyond a road edge;
* unsafe: against the neighbours' *predicted* futures (IDM prediction by default, the one every
  physics planner gets, never the recorded future), at any of the 125 frames a neighbour is in the
  ego's path (boxes overlapping laterally with ``lat_margin_m`` added) and closer bumper to bumper than
  ``front_gap_m`` (ahead) / ``rear_gap_m`` (behind) or than ``ttc_s`` times the closing speed (a
  1-D TTC below ``ttc_s``: the thresholds ``sf-opt`` and LetsPi's reflection use). Contact (plain box
  overlap) is a special case.

The cheapest valid candidate wins. When none is valid, the *least unsafe* one: the latest first
contact with a predicted neighbour (then the fewest contact (neighbour, frame) pairs), then feasible
before infeasible, then the latest and fewest margin violations, then cost.

Batched: the lattice is evaluated as arrays (B, I, F) and (B, J, F); the pair checks need no
(B, I, J, F) float array because a pair overlaps a neighbour at a frame exactly when its longitudinal
candidate overlaps longitudinally *and* its lateral candidate overlaps laterally: the per-candidate
flags are packed into bit strings and every pair is one AND of two of them. Costs add the same way.
No Python loop runs over scenarios or candidates (only over chunks of scenarios, to bound memory).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from letspi.constants import DT_S, HORIZON_S, N_FUTURE, T0_INDEX
from letspi.metrics.kinematics import off_road
from letspi.physics.goals import GoalPredictor, KinematicGoalPredictor
from letspi.physics.lanes import lane_centres_m, lane_index_of
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.types import NeighbourPrediction
from letspi.planners.base import PlanBatch
from letspi.planners.config import Config, GoalsConfig
from letspi.scenario.types import ScenarioBatch

SHIPPED_WEIGHTS_FILE = "frenet_weights.json"
#: lower bound of the speed in the curvature bound [m/s] (the bound is 1 / v²; a standing car cannot steer sideways)
CURVATURE_SPEED_FLOOR_MPS = 0.5
LON_SPEED, LON_FOLLOW = 0, 1
ANY_LANE = -9  # lane code of longitudinal candidates that pair with every lateral candidate


class FrenetWeights(BaseModel):
    """Cost weights. The defaults are hand-set starting values of ``letspi fit frenet``; the planner uses the
    fitted ones shipped in ``letspi/data/frenet_weights.json`` (``shipped_settings``).

    Units: k_jerk_lon, k_jerk_lat per (m²/s⁵) (the integral of squared jerk over the horizon);
    k_time per s of horizon; k_offset per m² of end offset from the target lane's centre; k_goal_lane
    per lane between the target lane and the goal's lane; k_speed per (m/s)² of mean-speed deviation
    from the desired speed. Only ratios matter (the argmin is
    unchanged when all are scaled), so ``k_speed`` is the unit the others are measured in.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    k_jerk_lon: float = Field(default=0.1, ge=0)
    k_jerk_lat: float = Field(default=0.1, ge=0)
    k_time: float = Field(default=0.1, ge=0)
    k_offset: float = Field(default=1.0, ge=0)
    k_goal_lane: float = Field(default=10.0, ge=0)
    k_speed: float = Field(default=1.0, ge=0)


WEIGHT_NAMES: tuple[str, ...] = tuple(FrenetWeights.model_fields)


class FrenetSampling(BaseModel):
    """The lattice (the same for every scenario). Defaults: horizons 3, 4, 5 s; current, left and right
    lane, centre and ±0.5 m; goal speed ±2 m/s; current speed -8, -4, 0, +2 m/s; a stop (0 m/s);
    following at 1 and 2 s, 3 m behind the leader (more than the safety check's front gap)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    horizons_s: tuple[float, ...] = (3.0, 4.0, 5.0)
    lane_changes: tuple[int, ...] = (0, 1, -1)  # lanes relative to the current one, +1 = left (+y)
    lateral_offsets_m: tuple[float, ...] = (0.0, -0.5, 0.5)
    goal_speed_offsets_mps: tuple[float, ...] = (0.0, -2.0, 2.0)
    current_speed_offsets_mps: tuple[float, ...] = (0.0, -4.0, -8.0, 2.0)
    absolute_speeds_mps: tuple[float, ...] = (0.0,)  # e.g. stopping
    follow_headways_s: tuple[float, ...] = (1.0, 2.0)
    follow_gap_m: float = Field(default=3.0, ge=0)  # > the safety check's front gap


class FrenetLimits(BaseModel):
    """Feasibility limits: the metric's success test allows 8 m/s² longitudinal and 4 m/s² lateral."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    max_accel_mps2: float = Field(default=4.0, gt=0)
    max_decel_mps2: float = Field(default=8.0, gt=0)
    max_lat_accel_mps2: float = Field(default=3.5, gt=0)
    max_curvature_1pm: float = Field(default=0.2, gt=0)
    min_speed_mps: float = -0.1  # below: the candidate drives backwards


class FrenetSafety(BaseModel):
    """The collision check against the predicted neighbours (margins; module doc)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    front_gap_m: float = Field(default=2.0, ge=0)
    rear_gap_m: float = Field(default=0.5, ge=0)
    ttc_s: float = Field(default=1.5, ge=0)
    lat_margin_m: float = Field(default=0.3, ge=0)


class FrenetSettings(BaseModel):
    """Everything that changes a ``frenet`` plan besides the goal source and the neighbour prediction."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    weights: FrenetWeights = Field(default_factory=FrenetWeights)
    sampling: FrenetSampling = Field(default_factory=FrenetSampling)
    limits: FrenetLimits = Field(default_factory=FrenetLimits)
    safety: FrenetSafety = Field(default_factory=FrenetSafety)


class FrenetConfig(Config):
    """``frenet``: the lattice planner; ``frenet`` holds its weights (the fitted values; ``weights_source``
    names their file), sample sets, limits and safety margins."""

    cosmetic: ClassVar[frozenset[str]] = frozenset({"weights_source"})

    kind: Literal["frenet"] = "frenet"
    neighbours: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    goals: GoalsConfig
    frenet: FrenetSettings = Field(default_factory=FrenetSettings)
    weights_source: str = "shipped"


def load_frenet_weights(path: Path | None = None) -> tuple[FrenetWeights, dict[str, Any]]:
    """Weights and the whole record (provenance, objective) from ``path`` (default: the shipped fit)."""
    if path is None:
        text = resources.files("letspi.data").joinpath(SHIPPED_WEIGHTS_FILE).read_text()
        where = f"letspi/data/{SHIPPED_WEIGHTS_FILE}"
    else:
        try:
            text = Path(path).read_text()
        except FileNotFoundError as exc:
            raise FileNotFoundError(f"{path}: no such frenet weights file (create one with `letspi fit frenet`)") \
                from exc
        where = str(path)
    try:
        record = json.loads(text)
        weights = FrenetWeights(**record["weights"])
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{where}: not a valid frenet weights file ({exc})") from exc
    return weights, record


def save_frenet_weights(path: Path, weights: FrenetWeights, provenance: dict[str, Any],
                        objective: dict[str, Any]) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    record = {"weights": weights.model_dump(), "provenance": provenance, "objective": objective}
    path.write_text(json.dumps(record, indent=2) + "\n")
    return path


# ------------------------------------------------------------------------------------------------
# Polynomials
# ------------------------------------------------------------------------------------------------


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


# ------------------------------------------------------------------------------------------------
# The lattice
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Lattice:
    """Weight-independent part of the planner for B scenarios: candidates, their checks and cost terms.

    Longitudinal (B, I): ``lon_coef`` (B, I, 6), ``lon_horizon_s`` (I,), ``lon_mode`` (I,) (0 speed, 1
    follow), ``lon_lane`` (I,) lane change the candidate pairs with (``ANY_LANE`` for all),
    ``lon_target_speed_mps``, ``lon_exists``, ``lon_feasible``, ``lon_jerk``, ``lon_mean_speed_mps``.
    Lateral (B, J): ``lat_coef`` (B, J, 6), ``lat_horizon_s`` (J,), ``lat_lane`` (J,), ``lat_offset_m``
    (J,), ``lat_target_y_m``, ``lat_exists``, ``lat_feasible``, ``lat_jerk``, ``lat_lanes_from_goal`` (lanes
    between the target lane and the goal's lane).
    Pairs (B, I, J): ``pair_ok`` (both exist and pair), ``feasible`` (with the curvature bound),
    ``contact`` and ``violation`` (unsafety scores of predicted contacts / margin violations, 0 = none;
    ``_pair_counts``).
    Per scenario (B,): ``v_des_mps``, ``goals_xy_m`` (B, 2).
    """

    lon_coef: np.ndarray
    lon_horizon_s: np.ndarray
    lon_mode: np.ndarray
    lon_lane: np.ndarray
    lon_target_speed_mps: np.ndarray
    lon_exists: np.ndarray
    lon_feasible: np.ndarray
    lon_jerk: np.ndarray
    lon_mean_speed_mps: np.ndarray
    lat_coef: np.ndarray
    lat_horizon_s: np.ndarray
    lat_lane: np.ndarray
    lat_offset_m: np.ndarray
    lat_target_y_m: np.ndarray
    lat_exists: np.ndarray
    lat_feasible: np.ndarray
    lat_jerk: np.ndarray
    lat_lanes_from_goal: np.ndarray
    pair_ok: np.ndarray
    feasible: np.ndarray
    contact: np.ndarray
    violation: np.ndarray
    v_des_mps: np.ndarray
    goals_xy_m: np.ndarray

    def __len__(self) -> int:
        return int(self.lon_coef.shape[0])

    @property
    def valid(self) -> np.ndarray:
        """(B, I, J) bool: existing, feasible and clear of every predicted neighbour with margins."""
        out: np.ndarray = self.pair_ok & self.feasible & (self.violation == 0)
        return out

    def cost(self, w: FrenetWeights) -> np.ndarray:
        """(B, I, J) cost of every pair (module doc); inf for pairs that do not exist."""
        lon = (w.k_jerk_lon * self.lon_jerk + w.k_time * self.lon_horizon_s[None, :]
               + w.k_speed * (self.lon_mean_speed_mps - self.v_des_mps[:, None]) ** 2)
        lat = (w.k_jerk_lat * self.lat_jerk + w.k_time * self.lat_horizon_s[None, :]
               + w.k_offset * self.lat_offset_m[None, :] ** 2 + w.k_goal_lane * self.lat_lanes_from_goal)
        total = lon[:, :, None] + lat[:, None, :]
        return np.where(self.pair_ok, total, np.inf)

    def choose(self, w: FrenetWeights) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Chosen (i, j) per scenario, (B,) each, with its cost and the number of valid pairs."""
        b, _, n_j = self.pair_ok.shape
        cost = self.cost(w).reshape(b, -1)
        valid = self.valid.reshape(b, -1)
        n_valid = valid.sum(axis=1)
        best_valid = np.argmin(np.where(valid, cost, np.inf), axis=1)
        # least unsafe: fewest weighted contacts, then feasible, then fewest margin violations, then cost
        ok = self.pair_ok.reshape(b, -1)
        pick = ok.copy()
        for key in (self.contact.reshape(b, -1), ~self.feasible.reshape(b, -1), self.violation.reshape(b, -1)):
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
        x, vx, _ = evaluate_held(self.lon_coef[rows, i], self.lon_horizon_s[i], t_s)
        y, vy, _ = evaluate_held(self.lat_coef[rows, j], self.lat_horizon_s[j], t_s)
        return np.stack([x, y], axis=-1), np.stack([vx, vy], axis=-1)

    def take(self, index: np.ndarray) -> Lattice:
        """The lattice of scenarios ``index`` (candidate-axis arrays are shared)."""
        shared = {"lon_horizon_s", "lon_mode", "lon_lane", "lat_horizon_s", "lat_lane", "lat_offset_m"}
        return Lattice(**{name: (value if name in shared else value[index])
                          for name, value in self.__dict__.items()})


def _lon_grid(s: FrenetSampling) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per longitudinal candidate: horizon, mode, lane change (following) and a parameter (speed offset
    or headway) and its kind (0 goal speed, 1 current speed, 2 following, 3 absolute speed), (I, 2)."""
    rows: list[tuple[float, int, int, float, int]] = []  # horizon, mode, lane, value, kind
    for t in s.horizons_s:
        rows += [(t, LON_SPEED, ANY_LANE, d, 0) for d in s.goal_speed_offsets_mps]
        rows += [(t, LON_SPEED, ANY_LANE, d, 1) for d in s.current_speed_offsets_mps]
        rows += [(t, LON_SPEED, ANY_LANE, v, 3) for v in s.absolute_speeds_mps]
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
        parts = [build_lattice(batch.take(slice(k, k + chunk_size)),
                               NeighbourPrediction(*(a[k:k + chunk_size] for a in pred)),
                               goals_xy_m[k:k + chunk_size], settings, chunk_size)
                 for k in range(0, len(batch), chunk_size)]
        return _concat(parts)
    return _build_chunk(batch, pred, np.asarray(goals_xy_m, dtype=np.float64), settings)


def _concat(parts: list[Lattice]) -> Lattice:
    shared = {"lon_horizon_s", "lon_mode", "lon_lane", "lat_horizon_s", "lat_lane", "lat_offset_m"}
    first = parts[0]
    return Lattice(**{name: (getattr(first, name) if name in shared
                             else np.concatenate([getattr(p, name) for p in parts], axis=0))
                      for name in first.__dict__})


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
                  ax0=np.clip(a_now[:, 0], -lim.max_decel_mps2, lim.max_accel_mps2),
                  ay0=np.clip(a_now[:, 1], -lim.max_lat_accel_mps2, lim.max_lat_accel_mps2), marks=marks,
                  centres=centres, n_lanes=np.isfinite(centres).sum(axis=1), cur=cur, progress=progress, v_des=v_des,
                  goal_lane=goal_lane)


def _lateral(batch: ScenarioBatch, st: _Start, s: FrenetSampling, lim: FrenetLimits, t_s: np.ndarray,
             ) -> dict[str, np.ndarray]:
    """Lateral candidates (B, J): coefficients, trajectories, checks and cost terms."""
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
    return {"t": lat_t, "lane": lat_lane, "off": lat_off, "y1": y1, "exists": exists, "coef": coef, "y": y,
            "peak_ay": peak_ay, "peak_vy": np.abs(vy).max(axis=2),
            "feasible": exists & ~leaves_road & (peak_ay <= lim.max_lat_accel_mps2),
            "jerk": jerk_integral(coef, lat_t[None, :]),
            "from_goal": np.abs(target_idx - st.goal_lane[:, None]).astype(np.float64)}


def _longitudinal(batch: ScenarioBatch, pred: NeighbourPrediction, st: _Start, s: FrenetSampling,
                  lim: FrenetLimits, t_s: np.ndarray) -> dict[str, np.ndarray]:
    """Longitudinal candidates (B, I): coefficients, trajectories, checks and cost terms."""
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
    coef = np.where(follow[None, :, None], coef_follow, coef_speed)
    exists = np.where(follow[None, :], lead_ok, True)
    x, vx, ax = evaluate_held(coef, np.broadcast_to(lon_t, (b, len(lon_t))), t_s)  # (B, I, F)
    feasible = (exists & (ax.max(axis=2) <= lim.max_accel_mps2 + 1e-9)
                & (ax.min(axis=2) >= -lim.max_decel_mps2 - 1e-9) & (vx.min(axis=2) >= lim.min_speed_mps))
    return {"t": lon_t, "mode": lon_mode, "lane": lon_lane, "coef": coef, "x": x, "vx": vx,
            "target_speed": np.where(follow[None, :], lead_v, v_speed), "exists": exists, "feasible": feasible,
            "jerk": jerk_integral(coef, tt), "mean_speed": (x[:, :, -1] - st.x0[:, None]) / HORIZON_S,
            "v_min": vx.min(axis=2), "peak_ax": np.abs(ax).max(axis=2)}


def _build_chunk(batch: ScenarioBatch, pred: NeighbourPrediction, goals_xy_m: np.ndarray,
                 settings: FrenetSettings) -> Lattice:
    s, lim = settings.sampling, settings.limits
    t_s = np.arange(1, N_FUTURE + 1) * DT_S  # (F,)
    st = _start(batch, goals_xy_m, lim)
    lat = _lateral(batch, st, s, lim, t_s)
    lon = _longitudinal(batch, pred, st, s, lim, t_s)
    # pairs: which exist, the curvature bound |κ| <= (|ay| |vx| + |vy| |ax|) / vx³ with separable maxima
    pairs_lane = (lon["lane"][:, None] == ANY_LANE) | (lon["lane"][:, None] == lat["lane"][None, :])  # (I, J)
    pair_ok = pairs_lane[None] & lon["exists"][:, :, None] & lat["exists"][:, None, :]
    v_min = np.maximum(lon["v_min"], CURVATURE_SPEED_FLOOR_MPS)[:, :, None]
    kappa = lat["peak_ay"][:, None, :] / v_min**2 + lat["peak_vy"][:, None, :] * lon["peak_ax"][:, :, None] / v_min**3
    feasible = lon["feasible"][:, :, None] & lat["feasible"][:, None, :] & (kappa <= lim.max_curvature_1pm)
    contact, violation = _pair_counts(batch, pred, lon["x"], lon["vx"], lat["y"], settings.safety)
    return Lattice(
        lon_coef=lon["coef"], lon_horizon_s=lon["t"], lon_mode=lon["mode"], lon_lane=lon["lane"],
        lon_target_speed_mps=lon["target_speed"], lon_exists=lon["exists"], lon_feasible=lon["feasible"],
        lon_jerk=lon["jerk"], lon_mean_speed_mps=lon["mean_speed"], lat_coef=lat["coef"], lat_horizon_s=lat["t"],
        lat_lane=lat["lane"], lat_offset_m=lat["off"], lat_target_y_m=lat["y1"], lat_exists=lat["exists"],
        lat_feasible=lat["feasible"], lat_jerk=lat["jerk"], lat_lanes_from_goal=lat["from_goal"], pair_ok=pair_ok,
        feasible=feasible, contact=contact, violation=violation, v_des_mps=st.v_des,
        goals_xy_m=np.asarray(goals_xy_m, dtype=np.float64),
    )


def _pair_counts(batch: ScenarioBatch, pred: NeighbourPrediction, x: np.ndarray, vx: np.ndarray, y: np.ndarray,
                 safety: FrenetSafety) -> tuple[np.ndarray, np.ndarray]:
    """Unsafety scores (B, I, J) int64 of every pair: contacts and margin violations with the predicted
    neighbours; 0 = none.

    A pair (i, j) overlaps neighbour n at frame f iff candidate i overlaps it longitudinally and j
    laterally. The per-candidate flags are packed into bits ((frame, neighbour) order, 8 frames of 8
    neighbours per 64-bit word), so a pair's overlaps are the AND of two bit strings: no (B, I, J, F)
    array and no BLAS call (whose threads stall on a busy machine). Score = (W - first word with an
    overlap) x 1,000,000 + number of overlapping (neighbour, frame) pairs, W = words per plan: an
    earlier first overlap (0.32 s resolution) is worse, then a longer or wider one.
    x, vx: (B, I, F) longitudinal candidates; y: (B, J, F) lateral candidates; float32 arithmetic
    (positions within a few hundred metres: sub-millimetre resolution).
    """
    valid = (pred.valid & np.isfinite(pred.xy_m).all(axis=-1)).transpose(0, 2, 1)[:, None]  # (B, 1, F, N)
    xn = pred.xy_m[..., 0].astype(np.float32).transpose(0, 2, 1)[:, None]
    yn = pred.xy_m[..., 1].astype(np.float32).transpose(0, 2, 1)[:, None]
    vn = pred.vxy_mps[..., 0].astype(np.float32).transpose(0, 2, 1)[:, None]
    half_len = (0.5 * (batch.ego_length_m[:, None] + np.nan_to_num(batch.nbr_length_m))).astype(np.float32)
    half_wid = (0.5 * (batch.ego_width_m[:, None] + np.nan_to_num(batch.nbr_width_m))).astype(np.float32)
    half_len = half_len[:, None, None, :]  # (B, 1, 1, N)
    half_wid = half_wid[:, None, None, :]

    xe = x.astype(np.float32)[..., None]  # (B, I, F, 1)
    dx = xn - xe  # (B, I, F, N), > 0: the neighbour is ahead
    closing = vx.astype(np.float32)[..., None] - vn  # ego faster: closing on a vehicle ahead
    front = half_len + np.maximum(np.float32(safety.front_gap_m), np.float32(safety.ttc_s) * closing)
    rear = half_len + np.maximum(np.float32(safety.rear_gap_m), np.float32(safety.ttc_s) * -closing)
    lon_contact = (np.abs(dx) < half_len) & valid
    lon_margin = (dx < front) & (dx > -rear) & valid
    dy = np.abs(yn - y.astype(np.float32)[..., None])  # (B, J, F, N)
    lat_contact = dy < half_wid
    lat_margin = dy < half_wid + np.float32(safety.lat_margin_m)
    return _and_score(_bits(lon_contact), _bits(lat_contact)), _and_score(_bits(lon_margin), _bits(lat_margin))


def _bits(flags: np.ndarray) -> np.ndarray:
    """(B, K, F, N) bool -> (B, K, W) uint64 bit strings (frame-major, zero padded)."""
    b, k = flags.shape[:2]
    packed = np.packbits(flags, axis=-1).reshape(b, k, -1)  # (B, K, F * ceil(N / 8)) bytes
    pad = (-packed.shape[2]) % 8
    if pad:
        packed = np.concatenate([packed, np.zeros((b, k, pad), dtype=np.uint8)], axis=2)
    return np.ascontiguousarray(packed).view(np.uint64)


def _and_score(lon_bits: np.ndarray, lat_bits: np.ndarray) -> np.ndarray:
    """Scores (B, I, J) of the pairwise ANDs of (B, I, W) and (B, J, W) bit strings (``_pair_counts``)."""
    both = lon_bits[:, :, None, :] & lat_bits[:, None, :, :]  # (B, I, J, W)
    hit = both != 0
    n_words = both.shape[3]
    count = np.bitwise_count(both).sum(axis=3, dtype=np.int64)
    first = np.where(hit.any(axis=3), hit.argmax(axis=3), n_words)
    out: np.ndarray = (n_words - first).astype(np.int64) * 1_000_000 + count
    return out


# ------------------------------------------------------------------------------------------------
# The planner
# ------------------------------------------------------------------------------------------------


def shipped_settings() -> FrenetSettings:
    """The default lattice with the shipped (fitted) weights."""
    return FrenetSettings(weights=load_frenet_weights()[0])


@dataclass
class FrenetPlanner:
    """Planner ``frenet`` (module doc); by default with the shipped weights. ``info`` per scenario: the chosen
    candidate's lane change (``target_lane``: -1 right, 0 keep, +1 left), lateral offset, longitudinal mode
    (0 speed, 1 follow), target speed, both horizons, its cost, ``n_safe`` (valid candidates) and
    ``found_safe``."""

    settings: FrenetSettings = field(default_factory=shipped_settings)
    goal_predictor: GoalPredictor = field(default_factory=KinematicGoalPredictor)
    neighbour_mode: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    name: str = "frenet"
    batch_size: int = 1024
    reads_future: bool = False

    def lattice(self, batch: ScenarioBatch) -> Lattice:
        goals = self.goal_predictor.predict_goals(batch).top
        return build_lattice(batch, predict_neighbours(batch, self.neighbour_mode), goals, self.settings)

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        lat = self.lattice(batch)
        return plan_from_lattice(lat, self.settings.weights)


def plan_from_lattice(lat: Lattice, weights: FrenetWeights) -> PlanBatch:
    """Choose with ``weights`` and return the plans with their ``info``."""
    i, j, cost, n_valid = lat.choose(weights)
    xy, vxy = lat.plans(i, j)
    rows = np.arange(len(lat))
    info = {
        "target_lane": lat.lat_lane[j].astype(np.int64),
        "lateral_offset_m": lat.lat_offset_m[j],
        "lateral_horizon_s": lat.lat_horizon_s[j],
        "lon_mode": lat.lon_mode[i].astype(np.int64),
        "target_speed_mps": lat.lon_target_speed_mps[rows, i],
        "lon_horizon_s": lat.lon_horizon_s[i],
        "cost": cost,
        "n_safe": n_valid.astype(np.int64),
        "found_safe": n_valid > 0,
    }
    return PlanBatch(xy_m=xy, vxy_mps=vxy, goals_xy_m=lat.goals_xy_m.copy(), info=info)
