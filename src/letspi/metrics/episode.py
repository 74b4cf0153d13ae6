"""Per-episode metrics of a closed-loop episode in a reactive simulator (highway-env): one registry, one computation.

An episode is one ego among V - 1 other vehicles, states at T simulation frames (``t_s``), until the first
collision, leaving the road, or its end. ``EPISODE_METRICS`` declares every value once, as
``letspi.metrics.registry`` does for scenarios (rationale: notes/rationale-runtime-evaluation.md, "episode metrics");
``episode_metrics`` computes them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from letspi.metrics.config import MetricsConfig
from letspi.metrics.drac import drac
from letspi.metrics.fault import at_fault_collisions
from letspi.metrics.inputs import MetricInputs
from letspi.metrics.registry import HOW_DOC, MEAN_HOWS, RATE_HOWS, Agg, Metric
from letspi.metrics.ttc import ttc_1d

#: a longitudinal deceleration above this is a hard brake [m/s^2]
HARD_BRAKE_MPS2: Final = 4.0

EPISODE_METRICS: tuple[Metric, ...] = (
    Metric("success", "", "bool", "no collision and on the road until the episode ended (its duration, or the "
           "environment's goal)", None, (Agg("success_pct", "pct", "DiLu's success rate"),)),
    Metric("survival_s", "s", "float64", "seconds before the first collision or leaving the road; the episode's "
           "length without either", None, (Agg("survival_s", "finite_mean", "DiLu's success steps, in seconds"),)),
    Metric("collision", "", "bool", "the ego collided (highway-env's crash flag)", None,
           (Agg("collision_pct", "pct"),)),
    Metric("at_fault", "", "bool", "the ego caused its first collision (letspi.metrics.fault's rules)", None,
           (Agg("at_fault_pct", "pct"),)),
    Metric("off_road", "", "bool", "the ego left the road", None, (Agg("off_road_pct", "pct"),)),
    Metric("episode_s", "s", "float64", "simulated seconds of the episode", None,
           (Agg("episode_s", "finite_mean"),)),
    Metric("mean_speed_mps", "m/s", "float64", "the ego's mean speed over the episode as driven", None,
           (Agg("mean_speed_mps", "finite_mean", "so that stopping does not win"),)),
    Metric("distance_m", "m", "float64", "the ego's progress along the road", None,
           (Agg("distance_m", "finite_mean"),)),
    Metric("lane_changes_n", "count", "int64", "changes of the ego centre's lane between frames", None,
           (Agg("lane_changes_n", "finite_mean"),)),
    Metric("min_ttc_s", "s", "float64", "minimum 1-D TTC with the preceding vehicle; +inf never closing", None,
           (Agg("min_ttc_s", "capped_mean", "no closing leader counts as the cap", "ttc_cap_s"),
            Agg("low_ttc_pct", "pct_below", "", "low_ttc_s"))),
    Metric("hard_brakes_n", "count", "int64", f"times the ego's deceleration rose above {HARD_BRAKE_MPS2:g} m/s²",
           None, (Agg("hard_brakes_n", "finite_mean"),)),
    Metric("peak_jerk_mps3", "m/s³", "float64", "largest longitudinal jerk of the ego (magnitude) before any "
           "collision", None,
           (Agg("peak_jerk_mps3", "finite_mean"),)),
    Metric("planner_latency_s", "s", "float64", "mean wall time of a replan (NaN without plans)", None,
           (Agg("planner_latency_s", "finite_mean"),)),
    Metric("planner_latency_max_s", "s", "float64", "largest wall time of a replan (NaN without plans)", None,
           (Agg("planner_latency_max_s", "finite_mean"),)),
)
EPISODE_COLUMNS: Final = tuple(m.name for m in EPISODE_METRICS)


def settings_record() -> dict[str, Any]:
    """The fixed settings of the definitions (they join a results directory's identity)."""
    return {"hard_brake_mps2": HARD_BRAKE_MPS2, "columns": list(EPISODE_COLUMNS)}


@dataclass(frozen=True)
class EpisodeInputs:
    """One episode's recorded states (highway-env's frame: x along the road, y to the right of travel): t_s (T,)
    ascending; xy_m, vxy_mps (V, T, 2) box centres and velocities; length_m, width_m (V,); ego: the ego's row;
    crashed (V, T) bool (the simulator's flag, set at contact); ego_on_road (T,) bool; ego_lane (T,) int, the lane of
    the ego's centre (-1 off the road); latency_s (R,) wall time of each replan."""

    t_s: np.ndarray
    xy_m: np.ndarray
    vxy_mps: np.ndarray
    length_m: np.ndarray
    width_m: np.ndarray
    ego: int
    crashed: np.ndarray
    ego_on_road: np.ndarray
    ego_lane: np.ndarray
    latency_s: np.ndarray


def _first(flags: np.ndarray) -> int:
    return int(np.argmax(flags)) if flags.any() else -1


def metric_inputs(ep: EpisodeInputs, end: int) -> MetricInputs:
    """The ego (B = 1) and the other vehicles as neighbours over frames 0..``end`` in the ego frame (y left); an
    ego alone gets one empty slot (never valid), so every metric has its neighbour axis."""
    flip = np.array([1.0, -1.0])
    others = np.flatnonzero(np.arange(len(ep.length_m)) != ep.ego)
    xy = ep.xy_m[:, : end + 1] * flip
    vxy = ep.vxy_mps[:, : end + 1] * flip
    valid = np.ones((1, len(others), end + 1), dtype=bool)
    nbr_xy, nbr_v = xy[others][None], vxy[others][None]
    length, width = ep.length_m[others][None].astype(np.float64), ep.width_m[others][None].astype(np.float64)
    if not len(others):
        valid = np.zeros((1, 1, end + 1), dtype=bool)
        nbr_xy = nbr_v = np.full((1, 1, end + 1, 2), np.nan)
        length = width = np.zeros((1, 1))
    return MetricInputs(
        ego_xy_m=xy[ep.ego][None], ego_vxy_mps=vxy[ep.ego][None],
        ego_length_m=ep.length_m[[ep.ego]].astype(np.float64), ego_width_m=ep.width_m[[ep.ego]].astype(np.float64),
        nbr_xy_m=nbr_xy, nbr_vxy_mps=nbr_v, nbr_valid=valid, nbr_length_m=length, nbr_width_m=width,
    )


def _at_fault(ep: EpisodeInputs, inp: MetricInputs, crash: int, dt_s: float, config: MetricsConfig) -> bool:
    """Whether the ego caused the collision of frame ``crash``; ``inp`` covers frames 0..crash."""
    others = np.flatnonzero(np.arange(len(ep.length_m)) != ep.ego)
    new = ep.crashed[others, crash] & ~(ep.crashed[others, crash - 1] if crash > 0 else False)
    candidates = np.flatnonzero(new) if new.any() else np.flatnonzero(ep.crashed[others, crash])
    if not len(candidates):
        return False
    dist = np.hypot(*(ep.xy_m[others[candidates], crash] - ep.xy_m[ep.ego, crash]).T)
    slot = int(candidates[np.argmin(dist)])
    overlap = np.zeros(inp.nbr_valid.shape, dtype=bool)
    overlap[0, slot, crash] = True
    ttc = ttc_1d(inp)
    acc = np.diff(inp.ego_vxy_mps[..., 0], axis=1, prepend=inp.ego_vxy_mps[:, :1, 0]) / dt_s
    result = at_fault_collisions(inp, overlap, np.array([crash]), np.array([slot]), acc,
                                 drac(inp, ttc.preceding).drac_mps2, ttc.preceding.nbr,
                                 reaction_time_s=config.fault_reaction_time_s,
                                 comfort_decel_mps2=config.fault_comfort_decel_mps2, dt_s=dt_s)
    return bool(result.collision_at_fault[0])


def _kinematics(vxy_mps: np.ndarray, dt_s: float) -> tuple[int, float]:
    """(hard brakes, peak |longitudinal jerk|) of the ego's velocities (T, 2) in the ego frame."""
    if len(vxy_mps) < 2:
        return 0, float("nan")
    acc = np.diff(vxy_mps, axis=0) / dt_s
    braking = -acc[:, 0] > HARD_BRAKE_MPS2
    onsets = int(np.sum(braking & ~np.concatenate([[False], braking[:-1]])))
    jerk = np.diff(acc, axis=0) / dt_s
    return onsets, float(np.abs(jerk[:, 0]).max()) if len(jerk) else float("nan")


def episode_metrics(ep: EpisodeInputs, config: MetricsConfig | None = None) -> dict[str, Any]:
    """Every ``EPISODE_METRICS`` value of one episode (module doc), by name."""
    config = config or MetricsConfig()
    t = np.asarray(ep.t_s, dtype=np.float64)
    dt_s = float(np.median(np.diff(t))) if len(t) > 1 else config.dt_s
    crash = _first(ep.crashed[ep.ego])
    left = _first(~np.asarray(ep.ego_on_road, dtype=bool))
    failures = [f for f in (crash, left) if f >= 0]
    end = min(failures) if failures else len(t) - 1
    inp = metric_inputs(ep, end)
    speed = np.hypot(*ep.vxy_mps[ep.ego, : end + 1].T)
    lanes = np.asarray(ep.ego_lane)[: end + 1]
    on = lanes >= 0
    lane_changes = int(np.sum(np.diff(lanes[on]) != 0))
    hard, jerk = _kinematics(inp.ego_vxy_mps[0, : (crash if crash >= 0 else end) + 1], dt_s)
    latency = np.asarray(ep.latency_s, dtype=np.float64)
    return {
        "success": not failures,
        "survival_s": float(t[end] - t[0]),
        "collision": crash >= 0,
        "at_fault": crash >= 0 and _at_fault(ep, metric_inputs(ep, crash), crash, dt_s, config),
        "off_road": left >= 0,
        "episode_s": float(t[-1] - t[0]),
        "mean_speed_mps": float(speed.mean()),
        "distance_m": float(ep.xy_m[ep.ego, end, 0] - ep.xy_m[ep.ego, 0, 0]),
        "lane_changes_n": lane_changes,
        "min_ttc_s": float(ttc_1d(inp).min_ttc_s[0]),
        "hard_brakes_n": hard,
        "peak_jerk_mps3": jerk,
        "planner_latency_s": float(latency.mean()) if len(latency) else float("nan"),
        "planner_latency_max_s": float(latency.max()) if len(latency) else float("nan"),
    }


def reference_markdown() -> str:
    """Markdown reference of the per-episode columns and the keys they aggregate into (``docs/highway-env.md``)."""
    lines = ["| column | unit | dtype | meaning |", "|---|---|---|---|"]
    lines += [f"| `{m.name}` | {m.unit} | {m.dtype} | {m.doc} |" for m in EPISODE_METRICS]
    lines += ["", "| key | unit | from | how | 95 % interval |", "|---|---|---|---|---|",
              "| `n` | count | | number of episodes aggregated | |"]
    for m in EPISODE_METRICS:
        for a in m.aggregates:
            how = HOW_DOC[a.how].format(t=a.threshold).replace("scenarios", "episodes")
            doc = f"{how}; {a.doc}" if a.doc else how
            interval = "Wilson" if a.how in RATE_HOWS else "bootstrap over episodes" if a.how in MEAN_HOWS else ""
            lines.append(f"| `{a.key}` | {a.unit(m.unit)} | `{m.name}` | {doc} | {interval} |")
    return "\n".join(lines) + "\n"
