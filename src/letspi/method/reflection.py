"""Reflection (paper §III-E, Figure 3), independent of any LLM.

``simulate_proposal`` plans proposed parameters (shared with the planners); ``safety_report`` checks plans
against the predicted neighbours and locates each violation; ``SafetyReport.to_text`` is the report the
refinement prompt includes; ``reflect`` is the loop. Time convention (as in ``letspi.metrics``): ``step`` f
is future frame f, at ``(f + 1) * dt`` after t = 0; the text shows ``f + 1`` ("frame 60/125" = 2.40 s).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Final, Literal, NamedTuple

import numpy as np

from letspi.constants import DT_S
from letspi.method.thresholds import ReflectionThresholds
from letspi.metrics.collision import boxes_overlap
from letspi.metrics.inputs import MetricInputs, min_over_nbr_time
from letspi.metrics.kinematics import road_edges
from letspi.metrics.pet import pet_grid
from letspi.metrics.relative import relative_position
from letspi.physics.goals import (
    LANE_FACTOR_RANGE,
    LON_FACTOR_RANGE,
    NEUTRAL_LANE_FACTOR,
    NEUTRAL_LON_FACTOR,
    KinematicGoalPredictor,
    adjust_goals,
)
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.params import PARAM_NAMES, SocialForceParams
from letspi.physics.social_force import rollout_social_force
from letspi.physics.types import NeighbourPrediction
from letspi.safety.adverse import AdverseSettings, FutureChecks, adverse_futures, check_futures
from letspi.safety.plan_check import SafetyCheck, check_plans, predicted_inputs
from letspi.scenario.queries import lane_id_of
from letspi.scenario.types import ScenarioBatch

Relative = Literal["front", "rear", "left", "right", "none"]
Category = Literal["front", "rear", "side", "road", "dynamics"]


@dataclass(frozen=True)
class CheckKind:
    """One kind of violation the reflection reports: its name, its label in the report and its unit."""

    name: str
    label: str
    unit: str


#: every kind of violation, in the order a report lists them
CHECKS: Final[tuple[CheckKind, ...]] = (
    CheckKind("contact", "contact", "m"),
    CheckKind("front_ttc", "TTC", "s"),
    CheckKind("rear_ttc", "rear TTC", "s"),
    CheckKind("in_path_gap", "in-path gap", "m"),
    CheckKind("pet", "PET", "s"),
    CheckKind("off_road", "off-road", "m"),
    CheckKind("harsh_braking", "braking", "m/s^2"),
)
CHECK_KINDS: Final[dict[str, CheckKind]] = {c.name: c for c in CHECKS}
#: a ``CheckKind`` name
MetricName = str
METRIC_ORDER: Final[tuple[MetricName, ...]] = tuple(CHECK_KINDS)


# Proposals and simulation -------------------------------------------------------------------


@dataclass(frozen=True)
class Proposal:
    """One answer of a proposer. lon_factor in [0, 1] (0 = goal 20 % further, 0.4 unchanged, 1 = 30 % shorter);
    lane_factor in [-1, 1] (-1 = adjacent lane left, +1 right). prompt / reply: an LLM's raw texts;
    clamped_fields: values clamped into range; fallback: defaults, no answer; meta: JSON-serialisable extras."""

    params: SocialForceParams
    lon_factor: float = NEUTRAL_LON_FACTOR
    lane_factor: float = NEUTRAL_LANE_FACTOR
    rationale: str = ""
    prompt: str | None = None
    reply: str | None = None
    clamped_fields: tuple[str, ...] = ()
    fallback: bool = False
    meta: dict[str, Any] = field(default_factory=dict)

    def normalised(self) -> Proposal:
        """Parameters and factors clamped into their ranges (NaN -> neutral), names added to ``clamped_fields``."""
        params = self.params.clamped()
        changed = [n for n in PARAM_NAMES if not getattr(params, n) == getattr(self.params, n)]
        lon = _clip_factor(self.lon_factor, LON_FACTOR_RANGE, NEUTRAL_LON_FACTOR)
        lane = _clip_factor(self.lane_factor, LANE_FACTOR_RANGE, NEUTRAL_LANE_FACTOR)
        if not lon == self.lon_factor:
            changed.append("lon_factor")
        if not lane == self.lane_factor:
            changed.append("lane_factor")
        if not changed:
            return self
        names = tuple(dict.fromkeys((*self.clamped_fields, *changed)))
        return replace(self, params=params, lon_factor=lon, lane_factor=lane, clamped_fields=names)

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form (parameters by name)."""
        out = asdict(self)
        out["params"] = self.params.as_dict()
        out["clamped_fields"] = list(self.clamped_fields)
        return out


def _clip_factor(value: float, bounds: tuple[float, float], neutral: float) -> float:
    v = float(value)
    return neutral if not math.isfinite(v) else min(max(v, bounds[0]), bounds[1])


class SimulatedPlan(NamedTuple):
    """xy_m, vxy_mps (B, F, 2) planned ego states [m, m/s]; goals_xy_m (B, 2) the adjusted goals [m]."""

    xy_m: np.ndarray
    vxy_mps: np.ndarray
    goals_xy_m: np.ndarray


def simulate_proposal(batch: ScenarioBatch, params: SocialForceParams, lon_factor: np.ndarray, lane_factor: np.ndarray,
                      base_goals_xy_m: np.ndarray, neighbour_prediction: NeighbourPrediction) -> SimulatedPlan:
    """Adjust the goals (paper factors) and roll the social force model out against predicted neighbours.
    params (B,) (clamped here), lon_factor, lane_factor (B,), base_goals_xy_m (B, 2) [m, ego frame],
    neighbour_prediction (B, N, F, ...) -> plans (B, F, 2) and adjusted goals (B, 2)."""
    b = len(batch)
    goals = adjust_goals(np.asarray(base_goals_xy_m, dtype=np.float64).reshape(b, 2),
                         batch.ego_xy0_m.astype(np.float64), np.asarray(lon_factor, dtype=np.float64),
                         np.asarray(lane_factor, dtype=np.float64), batch.marking_y_m)
    roll = rollout_social_force(batch, params.clamped(), goals, neighbour_prediction)
    return SimulatedPlan(roll.xy_m, roll.vxy_mps, goals)


# Safety report ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Violation:
    """One violated threshold of one scenario, at its worst (contact, off-road: first) instant. value / threshold
    in ``unit`` (contact: box gap 0 vs min_dist_m; off_road: excursion beyond the edge [m] vs 0). step: future
    step (time_s = (step + 1) dt). nbr_slot -1, vehicle_id 0, nbr_lane_id 0 without a neighbour; ego_lane_id 0 =
    off the road. relative: the neighbour's side (contact: one step before the overlap). dx_m, dy_m: neighbour
    minus ego centre [m] (NaN without a neighbour)."""

    metric: MetricName
    value: float
    threshold: float
    unit: str
    step: int
    time_s: float
    nbr_slot: int
    vehicle_id: int
    nbr_lane_id: int
    ego_lane_id: int
    relative: Relative
    dx_m: float
    dy_m: float

    @property
    def category(self) -> Category:
        """front / rear / side (left or right) / road / dynamics: what the suggestion targets."""
        if self.metric == "off_road":
            return "road"
        if self.metric == "harsh_braking":
            return "dynamics"
        if self.relative in ("left", "right"):
            return "side"
        return "rear" if self.relative == "rear" else "front"

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class SafetyReport:
    """Safety of one planned trajectory against the predicted neighbours. ``metrics``: min_ttc_s,
    min_rear_ttc_s, min_path_gap_m, min_box_gap_m (+inf = no conflict), collision, off_road, safe (0/1),
    min_pet_s (if checked). ``pre_contact_metrics`` / ``first_contact_time_s``: with contact, the metrics before
    it (after a crash the numbers mean nothing), else None."""

    scenario_id: str
    violations: tuple[Violation, ...]
    metrics: dict[str, float]
    thresholds: ReflectionThresholds
    n_steps: int
    pre_contact_metrics: dict[str, float] | None = None
    first_contact_time_s: float | None = None

    @property
    def violated(self) -> bool:
        return bool(self.violations)

    @property
    def safe(self) -> bool:
        return not self.violations

    def severity(self) -> tuple[float, ...]:
        """Sort key, smaller is less unsafe: contact, off-road, number of violations, then the margins
        (min front/rear TTC capped at 10 s, min in-path gap capped at 50 m), negated."""
        m = self.metrics
        ttc = min(m["min_ttc_s"], m["min_rear_ttc_s"], 10.0)
        gap = min(m["min_path_gap_m"], 50.0)
        return (m["collision"], m["off_road"], float(len(self.violations)), -ttc, -gap)

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly (non-finite floats stay floats; see ``letspi.method.memory`` for storage)."""
        return {
            "scenario_id": self.scenario_id,
            "violated": self.violated,
            "metrics": dict(self.metrics),
            "violations": [v.to_dict() for v in self.violations],
            "thresholds": self.thresholds.model_dump(),
        }

    def to_text(self, proposal: Proposal | None = None) -> str:
        """The safety report for the refinement prompt; with ``proposal`` the suggestions quote its values."""
        th = self.thresholds
        checks = [f"TTC >= {th.ttc_s:g} s (front and rear)", f"in-path gap >= {th.min_dist_m:g} m", "no contact"]
        if th.pet_s is not None:
            checks.append(f"PET >= {th.pet_s:g} s")
        if th.check_off_road:
            checks.append("stay on the road")
        if th.max_decel_mps2 is not None:
            checks.append(f"braking <= {th.max_decel_mps2:g} m/s^2")
        horizon = f"{self.n_steps * DT_S:.1f} s"
        head = f"Safety analysis of the planned {horizon} trajectory (thresholds: {', '.join(checks)})"
        if not self.violations:
            return f"{head}: SAFE.\n{self._summary()}"
        lines = [f"{head}: UNSAFE, {len(self.violations)} violation(s)."]
        lines += [f"- {_violation_text(v, self.n_steps)}" for v in self.violations]
        lines.append("Suggestions:")
        lines += [f"- {s}" for s in _suggestions(self.violations, proposal)]
        lines.append(self._summary())
        return "\n".join(lines)

    def _summary(self) -> str:
        m = self.metrics if self.pre_contact_metrics is None else self.pre_contact_metrics
        parts = [
            f"min front TTC {_fmt(m['min_ttc_s'], 's')}",
            f"min rear TTC {_fmt(m['min_rear_ttc_s'], 's')}",
            f"min in-path gap {_fmt(m['min_path_gap_m'], 'm')}",
            f"min box gap {_fmt(m['min_box_gap_m'], 'm')}",
        ]
        if "min_pet_s" in m:
            parts.append(f"min PET {_fmt(m['min_pet_s'], 's')}")
        if self.first_contact_time_s is None:
            parts.append("contact no")
            head = "Summary"
        else:
            parts.append(f"contact at t={self.first_contact_time_s:.2f} s")
            head = "Summary (before the first contact)"
        parts.append(f"off-road {'yes' if self.metrics['off_road'] else 'no'}")
        return f"{head}: " + ", ".join(parts) + "."


def _fmt(value: float, unit: str) -> str:
    return "none" if not math.isfinite(value) else f"{value:.2f} {unit}"


def _where(v: Violation) -> str:
    if v.nbr_slot < 0:
        return ""
    same = v.nbr_lane_id != 0 and v.nbr_lane_id == v.ego_lane_id
    lane = "the same lane" if same else (f"lane {v.nbr_lane_id}" if v.nbr_lane_id else "off the road")
    phrase = {
        "front": f"ahead in {lane}",
        "rear": f"behind in {lane}",
        "left": f"on the left in {lane}",
        "right": f"on the right in {lane}",
        "none": f"in {lane}",
    }[v.relative]
    return f"vehicle #{v.vehicle_id} (slot {v.nbr_slot}) {phrase}, dx {v.dx_m:+.1f} m, dy {v.dy_m:+.1f} m"


def _violation_text(v: Violation, n_steps: int) -> str:
    ego_lane = f"in lane {v.ego_lane_id}" if v.ego_lane_id else "off the road"
    at = f"At t={v.time_s:.2f} s (frame {v.step + 1}/{n_steps}) {ego_lane}"
    cat = v.category if v.category != "side" else f"side ({v.relative})"
    if v.metric == "off_road":
        return f"{at}: the ego box extends {v.value:.2f} m beyond the road edge (off-road)."
    if v.metric == "harsh_braking":
        return (f"{at}: the ego brakes at {v.value:.1f} m/s^2 > {v.threshold:g} m/s^2 (harsh braking: not "
                "drivable comfortably, invites rear-end conflicts).")
    if v.metric == "contact":
        return f"{at}, {_where(v)}: boxes overlap (contact, {cat} collision)."
    label, unit = CHECK_KINDS[v.metric].label, CHECK_KINDS[v.metric].unit
    return f"{at}, {_where(v)}: {label} {v.value:.2f} {unit} < {v.threshold:g} {unit} ({cat} conflict)."


def _suggestions(violations: tuple[Violation, ...], proposal: Proposal | None) -> list[str]:
    """One targeted suggestion per category and side, in the order of first appearance."""

    def now(name: str) -> str:
        if proposal is None:
            return ""
        value = getattr(proposal.params, name) if name in PARAM_NAMES else getattr(proposal, name)
        return f" (now {value:.2f})"

    out: dict[str, str] = {}
    for v in violations:
        who = f"vehicle #{v.vehicle_id}"
        if v.category == "front":
            out.setdefault("front", f"Front conflict with {who}: increase k_np{now('k_np')} and shorten the goal "
                           f"(raise lon_factor towards 1{now('lon_factor')}).")
        elif v.category == "rear":
            out.setdefault("rear", f"Rear conflict with {who}: increase k_nf{now('k_nf')}; do not shorten the goal "
                           f"(keep lon_factor at or below {NEUTRAL_LON_FACTOR:g}{now('lon_factor')}: braking makes it "
                           "worse); consider the adjacent lane only if it is free.")
        elif v.category == "side":
            away = "towards +1 (right)" if v.relative == "left" else "towards -1 (left)"
            out.setdefault(f"side-{v.relative}", f"Side conflict with {who} on the {v.relative}: increase "
                           f"k_nl{now('k_nl')} and move the goal away from it (lane_factor {away}"
                           f"{now('lane_factor')}).")
        elif v.category == "dynamics":
            out.setdefault("dynamics", f"Harsh braking: increase tau{now('tau_s')} for smoother speed changes "
                           f"and do not shorten the goal so much (lon_factor towards {NEUTRAL_LON_FACTOR:g}"
                           f"{now('lon_factor')}) unless a front conflict requires it.")
        else:
            out.setdefault("road", f"The plan leaves the road: increase k_boundary{now('k_boundary')} and bring "
                           f"lane_factor back towards 0{now('lane_factor')}.")
    return list(out.values())


def _first_event(event: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(B, N, F) bool -> flag, first step, lowest slot at that step (B,) each; -1 when none."""
    per_step = np.any(event, axis=1)
    flag: np.ndarray = np.any(per_step, axis=1)
    step = np.where(flag, per_step.argmax(axis=1), -1)
    at = np.take_along_axis(event, np.maximum(step, 0)[:, None, None], axis=2)[:, :, 0]
    return flag, step, np.where(flag, at.argmax(axis=1), -1)


def safety_report(batch: ScenarioBatch, plan_xy_m: np.ndarray, plan_vxy_mps: np.ndarray,
                  neighbour_prediction: NeighbourPrediction, thresholds: ReflectionThresholds | None = None,
                  ) -> list[SafetyReport]:
    """Safety reports of B plans (B, F, 2) against predicted neighbours (B, N, F, ...), computed batched.
    Metrics cover the whole horizon; with contact, TTC / gap / PET violations are located before it.
    ``safe`` equals ``check_plans(...).safe(ttc_s, min_dist_m)`` when PET is off and off-road is checked."""
    th = thresholds or ReflectionThresholds()
    check = check_plans(batch, plan_xy_m, plan_vxy_mps, neighbour_prediction)  # whole horizon: the metrics
    inp = predicted_inputs(batch, plan_xy_m, plan_vxy_mps, neighbour_prediction)
    contact, c_step, c_nbr = _first_event(boxes_overlap(inp))
    pre, pre_inp = _before_contact(batch, plan_xy_m, plan_vxy_mps, neighbour_prediction, contact, c_step,
                                   check, inp)
    located = _located_metrics(batch, th, check, pre, pre_inp, contact, c_step, c_nbr)
    pet_s: np.ndarray | None = None
    pre_pet_s: np.ndarray | None = None
    if th.pet_s is not None:
        full_pet = pet_grid(inp, th.pet_cell_m)
        pet_s = full_pet.min_pet_s  # whole horizon, for the metrics
        pet = pet_grid(pre_inp, th.pet_cell_m) if contact.any() else full_pet
        pre_pet_s = pet.min_pet_s
        located["pet"] = (pet.min_pet_s, pet.min_pet_step, pet.min_pet_nbr, pet.min_pet_s < th.pet_s)
    if th.check_off_road:
        off_val, off_step = _off_road_excursion(batch, inp)
        located["off_road"] = (off_val, off_step, np.full(len(batch), -1), check.off_road)
    max_decel, brake_step = _peak_braking(batch, inp)
    if th.max_decel_mps2 is not None:
        located["harsh_braking"] = (max_decel, brake_step, np.full(len(batch), -1),
                                    max_decel > th.max_decel_mps2 + 1e-9)
    columns = _violation_columns(batch, inp, located)
    reports = []
    for i in range(len(batch)):
        violations = _violations_of(columns, i, th)
        reports.append(SafetyReport(
            scenario_id=str(batch.scenario_id[i]), violations=tuple(violations), thresholds=th, n_steps=inp.n_steps,
            metrics={**_metrics_row(check, i, pet_s, safe=not violations), "max_decel_mps2": float(max_decel[i])},
            pre_contact_metrics=_metrics_row(pre, i, pre_pet_s, safe=False) if contact[i] else None,
            first_contact_time_s=float((c_step[i] + 1) * DT_S) if contact[i] else None))
    return reports


#: metric -> (value, step, neighbour slot, violated), (B,) each
Located = dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]


def _before_contact(batch: ScenarioBatch, plan_xy_m: np.ndarray, plan_vxy_mps: np.ndarray,
                    neighbour_prediction: NeighbourPrediction, contact: np.ndarray, c_step: np.ndarray,
                    check: SafetyCheck, inp: MetricInputs) -> tuple[SafetyCheck, MetricInputs]:
    """The plan checks on the steps before each scenario's first contact (without contact: the given ones)."""
    if not contact.any():
        return check, inp
    # after a contact the plan means nothing: check_plans again on a prediction masked from that step on
    n_steps = inp.n_steps
    before = np.arange(n_steps)[None, :] < np.where(contact, c_step, n_steps)[:, None]  # (B, F)
    masked = NeighbourPrediction(neighbour_prediction.xy_m, neighbour_prediction.vxy_mps,
                                 np.asarray(neighbour_prediction.valid, dtype=bool) & before[:, None, :])
    return (check_plans(batch, plan_xy_m, plan_vxy_mps, masked),
            predicted_inputs(batch, plan_xy_m, plan_vxy_mps, masked))


def _located_metrics(batch: ScenarioBatch, th: ReflectionThresholds, check: SafetyCheck, pre: SafetyCheck,
                     pre_inp: MetricInputs, contact: np.ndarray, c_step: np.ndarray, c_nbr: np.ndarray) -> Located:
    """Contact, front and rear TTC and the in-path gap, each with where it occurs."""
    # in-path gap: where check_plans' min_path_gap_m occurs (same definition)
    in_path = pre_inp.lateral_overlap & pre_inp.nbr_valid
    _, gap_step, gap_nbr = min_over_nbr_time(
        np.where(in_path, np.abs(pre_inp.dx_m) - pre_inp.half_len_sum_m, np.inf))
    return {
        "contact": (np.zeros(len(batch)), c_step, c_nbr, contact),
        "front_ttc": (pre.min_ttc_s, pre.min_ttc_step, pre.min_ttc_nbr, pre.min_ttc_s < th.ttc_s),
        "rear_ttc": (pre.min_rear_ttc_s, pre.min_rear_ttc_step, pre.min_rear_ttc_nbr, pre.min_rear_ttc_s < th.ttc_s),
        "in_path_gap": (pre.min_path_gap_m, gap_step, gap_nbr, pre.min_path_gap_m < th.min_dist_m),
    }


def _off_road_excursion(batch: ScenarioBatch, inp: MetricInputs) -> tuple[np.ndarray, np.ndarray]:
    """(largest excursion of the ego box beyond a road edge [m], first step beyond it (-1: none)), (B,) each."""
    right, left = road_edges(batch.marking_y_m, batch.marking_is_edge)
    hw = 0.5 * inp.ego_width_m[:, None]
    ey = inp.ego_xy_m[..., 1]
    excess = np.maximum(right[:, None] - (ey - hw), (ey + hw) - left[:, None])  # (B, F), > 0 beyond
    beyond = excess > 0
    off_step = np.where(beyond.any(axis=1), beyond.argmax(axis=1), -1)
    off_val = np.where(beyond.any(axis=1), np.nanmax(np.where(beyond, excess, -np.inf), axis=1), 0.0)
    return off_val, off_step


def _peak_braking(batch: ScenarioBatch, inp: MetricInputs) -> tuple[np.ndarray, np.ndarray]:
    """(peak deceleration of the plan from the t = 0 velocity on [m/s²], its step), (B,) each."""
    vx = np.concatenate([batch.ego_vxy0_mps[:, None, 0].astype(np.float64), inp.ego_vxy_mps[..., 0]], axis=1)
    braking = -np.diff(vx, axis=1) / DT_S  # (B, F), > 0 when slowing down
    brake_step = np.nanargmax(np.where(np.isfinite(braking), braking, -np.inf), axis=1)
    return braking[np.arange(len(batch)), brake_step], brake_step


def _violation_columns(batch: ScenarioBatch, inp: MetricInputs, located: Located) -> dict[str, dict[str, np.ndarray]]:
    """Per metric, (B,) columns of every ``Violation`` field."""
    rows = np.arange(len(batch))
    ego_lane = lane_id_of(batch, inp.ego_xy_m[..., 1])  # (B, F)
    nbr_y = np.where(inp.nbr_valid, inp.nbr_xy_m[..., 1], np.nan)
    nbr_lane = lane_id_of(batch, nbr_y)  # (B, N, F)
    columns: dict[str, dict[str, np.ndarray]] = {}
    for metric, (value, step, nbr, bad) in located.items():
        step = np.asarray(step, dtype=np.int64)
        nbr = np.asarray(nbr, dtype=np.int64)
        s0, k0 = np.maximum(step, 0), np.maximum(nbr, 0)
        # contact: classify the approach (one step before the overlap), not the overlap itself
        rel_step = np.where(step > 0, step - 1, step) if metric == "contact" else step
        columns[metric] = {
            "value": np.asarray(value, dtype=np.float64),
            "step": step,
            "nbr": np.where(nbr >= 0, nbr, -1),
            "bad": np.asarray(bad, dtype=bool) & (step >= 0),
            "vehicle_id": np.where(nbr >= 0, batch.nbr_id[rows, k0], 0),
            "nbr_lane": np.where(nbr >= 0, nbr_lane[rows, k0, s0], 0),
            "ego_lane": np.where(step >= 0, ego_lane[rows, s0], 0),
            "relative": relative_position(inp, rel_step, nbr, left_right=True),
            "dx": np.where(nbr >= 0, inp.dx_m[rows, k0, s0], np.nan),
            "dy": np.where(nbr >= 0, inp.dy_m[rows, k0, s0], np.nan),
        }
    return columns


def _violations_of(columns: dict[str, dict[str, np.ndarray]], i: int, th: ReflectionThresholds) -> list[Violation]:
    """Scenario ``i``'s violations, in ``METRIC_ORDER``."""
    thresholds_of = {"contact": th.min_dist_m, "front_ttc": th.ttc_s, "rear_ttc": th.ttc_s,
                     "in_path_gap": th.min_dist_m, "pet": th.pet_s or 0.0, "off_road": 0.0,
                     "harsh_braking": th.max_decel_mps2 or 0.0}
    violations = []
    for metric in METRIC_ORDER:
        col = columns.get(metric)
        if col is None or not col["bad"][i]:
            continue
        step_i = int(col["step"][i])
        violations.append(Violation(
            metric=metric, value=float(col["value"][i]), threshold=float(thresholds_of[metric]),
            unit=CHECK_KINDS[metric].unit, step=step_i, time_s=(step_i + 1) * DT_S, nbr_slot=int(col["nbr"][i]),
            vehicle_id=int(col["vehicle_id"][i]), nbr_lane_id=int(col["nbr_lane"][i]),
            ego_lane_id=int(col["ego_lane"][i]), relative=str(col["relative"][i]),  # type: ignore[arg-type]
            dx_m=float(col["dx"][i]), dy_m=float(col["dy"][i])))
    return violations


def _metrics_row(check: SafetyCheck, i: int, pet_s: np.ndarray | None, *, safe: bool) -> dict[str, float]:
    row = {
        "min_ttc_s": float(check.min_ttc_s[i]),
        "min_rear_ttc_s": float(check.min_rear_ttc_s[i]),
        "min_path_gap_m": float(check.min_path_gap_m[i]),
        "min_box_gap_m": float(check.min_box_gap_m[i]),
        "collision": float(check.collision[i]),
        "off_road": float(check.off_road[i]),
    }
    if pet_s is not None:
        row["min_pet_s"] = float(pet_s[i])
    row["safe"] = float(safe)
    return row


# The loop -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class AdverseOutcome:
    """A plan against the adverse futures (``letspi.safety.adverse``): the futures it fails, in order,
    and for each the time of the first contact [s] (NaN: no contact, a TTC or gap below the adverse
    thresholds)."""

    failed: tuple[str, ...]
    contact_time_s: tuple[float, ...]

    def text(self) -> str:
        """``passes all adverse futures`` or ``fails leader-brakes (contact at 2.30 s), cut-in (near miss)``."""
        if not self.failed:
            return "passes all adverse futures"
        parts = [f"{name} ({'near miss' if not math.isfinite(t) else f'contact at {t:.2f} s'})"
                 for name, t in zip(self.failed, self.contact_time_s, strict=True)]
        return "fails " + ", ".join(parts)


def adverse_outcomes(checks: FutureChecks, settings: AdverseSettings) -> list[AdverseOutcome]:
    """Per scenario of ``checks``, the adverse futures its plan fails."""
    failed = checks.failed(settings)
    names = checks.names[1:]
    return [AdverseOutcome(tuple(names[a] for a in np.flatnonzero(row)),
                           tuple(float(checks.contact_time_s[i, 1 + a]) for a in np.flatnonzero(row)))
            for i, row in enumerate(failed)]


@dataclass(frozen=True)
class IterationRecord:
    """One proposal (``iteration`` 0 the initial one), its adjusted goal [m], plan (F, 2) (not serialised),
    safety report and wall times ``propose_s`` / ``simulate_s`` [s]."""

    iteration: int
    proposal: Proposal
    goal_xy_m: tuple[float, float]
    report: SafetyReport
    propose_s: float
    simulate_s: float
    plan_xy_m: np.ndarray = field(repr=False, compare=False)
    plan_vxy_mps: np.ndarray = field(repr=False, compare=False)
    adverse: AdverseOutcome | None = None

    @property
    def safe(self) -> bool:
        """Passes the checks against the prediction and, when they were checked, every adverse future."""
        return self.report.safe and (self.adverse is None or not self.adverse.failed)

    @property
    def predicted_safe(self) -> bool:
        """Passes the checks against the prediction (the paper's reflection)."""
        return self.report.safe

    @property
    def n_adverse_failed(self) -> int:
        return len(self.adverse.failed) if self.adverse is not None else 0

    @property
    def metrics(self) -> dict[str, float]:
        return self.report.metrics

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly record (proposal with prompt/reply, goal, metrics, report text and violations)."""
        return {
            "iteration": self.iteration,
            "proposal": self.proposal.to_dict(),
            "goal_xy_m": list(self.goal_xy_m),
            "safe": self.safe,
            "metrics": dict(self.report.metrics),
            "violations": [v.to_dict() for v in self.report.violations],
            "report_text": self.report.to_text(self.proposal),
            "adverse_failed": list(self.adverse.failed) if self.adverse is not None else [],
            "adverse_text": self.adverse.text() if self.adverse is not None else "",
            "propose_s": self.propose_s,
            "simulate_s": self.simulate_s,
        }


@dataclass(frozen=True)
class ReflectionContext:
    """What ``propose`` sees: a batch of one, its unadjusted goal (2,) [m], and earlier iterations (``history[-1]``
    produced ``previous`` / ``report``, both None at iteration 0)."""

    scenario: ScenarioBatch
    iteration: int
    base_goal_xy_m: np.ndarray
    previous: Proposal | None
    report: SafetyReport | None
    history: tuple[IterationRecord, ...]
    thresholds: ReflectionThresholds
    adverse: AdverseOutcome | None = None  # the previous plan against the adverse futures (when checked)


@dataclass(frozen=True)
class ReflectionResult:
    """All iterations of one scenario; ``final_index`` points at the one to use. ``validated``: some plan passed
    the checks against the prediction (final: the first also passing every adverse future, else the one
    failing fewest); otherwise final is the least unsafe (``unsafe_choice="best"``) or the last."""

    scenario_id: str
    iterations: tuple[IterationRecord, ...]
    final_index: int
    validated: bool

    @property
    def final(self) -> IterationRecord:
        return self.iterations[self.final_index]

    @property
    def initial(self) -> IterationRecord:
        return self.iterations[0]

    @property
    def n_refinements(self) -> int:
        """Proposals after the initial one that were made."""
        return len(self.iterations) - 1

    @property
    def metrics_before(self) -> dict[str, float]:
        return self.initial.metrics

    @property
    def metrics_after(self) -> dict[str, float]:
        return self.final.metrics


Proposer = Callable[[ReflectionContext], Proposal]


def _goal_and_prediction(scenario: ScenarioBatch, base_goal_xy_m: np.ndarray | None,
                         neighbour_prediction: NeighbourPrediction | None) -> tuple[np.ndarray, NeighbourPrediction]:
    """The goal before adjustment (2,) and the neighbour prediction (defaults: kinematic goal, IDM)."""
    if base_goal_xy_m is None:
        base_goal_xy_m = KinematicGoalPredictor().predict_goals(scenario).top[0]
    pred = neighbour_prediction if neighbour_prediction is not None else predict_neighbours(
        scenario, NeighbourPredictionMode.IDM)
    return np.asarray(base_goal_xy_m, dtype=np.float64).reshape(2), pred


def _with_goal_factors_of(proposal: Proposal, first: Proposal) -> Proposal:
    """``proposal`` with ``first``'s goal factors, an override recorded in ``meta['goal_factors_frozen']``."""
    if (proposal.lon_factor, proposal.lane_factor) == (first.lon_factor, first.lane_factor):
        return proposal
    meta = {**proposal.meta, "goal_factors_frozen": [proposal.lon_factor, proposal.lane_factor]}
    return replace(proposal, lon_factor=first.lon_factor, lane_factor=first.lane_factor, meta=meta)


def reflect(scenario: ScenarioBatch, propose: Proposer, thresholds: ReflectionThresholds | None = None, *,
            base_goal_xy_m: np.ndarray | None = None, neighbour_prediction: NeighbourPrediction | None = None,
            goal_adjustment: bool = True, unsafe_choice: Literal["best", "last"] = "best",
            adverse: AdverseSettings | None = None) -> ReflectionResult:
    """Propose, simulate, check; re-propose with the safety report until safe (paper Figure 3). ``scenario``: a
    batch of one; ``base_goal_xy_m`` (2,) and ``neighbour_prediction`` (1, N, F, ...) default as the planners'.
    ``goal_adjustment=False`` (the "w/o GA" ablation) keeps the first goal factors. Proposals are clamped
    (``normalised``) before simulation and recorded so. ``adverse``: plans failing an adverse future are refined
    too; ``ValueError`` for more than one scenario."""
    if len(scenario) != 1:
        raise ValueError(f"reflect works on one scenario (a batch of one), got {len(scenario)}")
    th = thresholds or ReflectionThresholds()
    base_goal, pred = _goal_and_prediction(scenario, base_goal_xy_m, neighbour_prediction)
    futures = adverse_futures(scenario, pred, adverse) if adverse is not None else None

    history: list[IterationRecord] = []
    for iteration in range(th.max_iterations + 1):
        last = history[-1] if history else None
        ctx = ReflectionContext(scenario=scenario, iteration=iteration, base_goal_xy_m=base_goal.copy(),
                                previous=last.proposal if last else None, report=last.report if last else None,
                                history=tuple(history), thresholds=th, adverse=last.adverse if last else None)
        t0 = time.perf_counter()
        proposal = propose(ctx).normalised()
        t1 = time.perf_counter()
        if not goal_adjustment and history:
            proposal = _with_goal_factors_of(proposal, history[0].proposal)
        plan = simulate_proposal(scenario, SocialForceParams.stack([proposal.params]), np.array([proposal.lon_factor]),
                                 np.array([proposal.lane_factor]), base_goal[None], pred)
        report = safety_report(scenario, plan.xy_m, plan.vxy_mps, pred, th)[0]
        outcome = None
        if futures is not None and adverse is not None:
            outcome = adverse_outcomes(check_futures(scenario, plan.xy_m, plan.vxy_mps, pred, futures), adverse)[0]
        t2 = time.perf_counter()
        history.append(IterationRecord(
            iteration=iteration, proposal=proposal, report=report, propose_s=t1 - t0, simulate_s=t2 - t1,
            goal_xy_m=(float(plan.goals_xy_m[0, 0]), float(plan.goals_xy_m[0, 1])),
            plan_xy_m=plan.xy_m[0], plan_vxy_mps=plan.vxy_mps[0], adverse=outcome))
        if history[-1].safe:
            break

    return ReflectionResult(scenario_id=str(scenario.scenario_id[0]), iterations=tuple(history),
                            final_index=_final_index(history, unsafe_choice),
                            validated=any(rec.predicted_safe for rec in history))


def _final_index(history: list[IterationRecord], unsafe_choice: Literal["best", "last"]) -> int:
    """The iteration that is the result: the first safe one (prediction and adverse futures), else the
    first safe against the prediction with the fewest adverse failures, else the last or the least severe."""
    safe_idx = [i for i, rec in enumerate(history) if rec.safe]
    if safe_idx:
        return safe_idx[0]
    predicted = [i for i, rec in enumerate(history) if rec.predicted_safe]
    if predicted:
        return min(predicted, key=lambda i: (history[i].n_adverse_failed, i))
    if unsafe_choice == "last":
        return len(history) - 1
    return min(range(len(history)), key=lambda i: (history[i].report.severity(), -i))
