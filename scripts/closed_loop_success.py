"""Where a planner loses success (SR) against a reference in closed loop, window by window, pooled over results.

Usage: python scripts/closed_loop_success.py PLANNER REFERENCE RESULTS_DIR [RESULTS_DIR ...]

Each RESULTS_DIR is a closed-loop results directory (``letspi evaluate --mode closed-loop-log`` or a suite's
``closed-loop-log-0.2s``) holding both planners; its ``run.json`` names the scenario file (the recorded
human endpoint and the lane markings come from there). Windows are paired by scenario digest. Prints JSON:
the windows only the reference succeeds in ("lost") and only the planner ("gained"); why each lost one
failed: a contact, the simulated ego ends in another lane than the human ("lane"), short of or beyond the
human's progress ("short", "long"), a peak acceleration over the limits ("infeasible"), else off the road or
not finite ("other"), and the same for the reference in the gained ones, with the peak |a_lon| range of the
infeasible plans; and what the planner had in
force over the window's replans (from ``info_lon_factor_mean_over_replans`` / ``info_lane_factor_...``):
a right-lane preset at some replan ("lane change"), a goal nearer than the defaults' ("cautious"), or the
defaults throughout ("defaults").
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pandas as pd

from letspi.analysis.decisions import paired_rows
from letspi.constants import N_FUTURE, T0_INDEX
from letspi.metrics.config import MetricsConfig
from letspi.metrics.kinematics import lane_index
from letspi.physics.goals import NEUTRAL_LON_FACTOR
from letspi.scenario.identity import scenario_digests
from letspi.scenario.store import load_scenarios
from letspi.scenario.types import ScenarioBatch

LON, LANE = "info_lon_factor_mean_over_replans", "info_lane_factor_mean_over_replans"


def _ends(plans: pd.Series) -> np.ndarray:
    """(n, 2) the simulated ego's final centre of each row."""
    return np.array([np.asarray(p, dtype=np.float64).reshape(N_FUTURE, 2)[-1] for p in plans])


def _in_force(frame: pd.DataFrame) -> np.ndarray:
    """(n,) str: what the planner had in force over the replans (module docstring)."""
    n = len(frame)
    lon = frame[LON].to_numpy(np.float64) if LON in frame else np.full(n, NEUTRAL_LON_FACTOR)
    lane = frame[LANE].to_numpy(np.float64) if LANE in frame else np.zeros(n)
    return np.where(np.abs(lane) > 1e-9, "lane change", np.where(lon > NEUTRAL_LON_FACTOR + 1e-9, "cautious",
                                                                  "defaults"))


def _why(frame: pd.DataFrame, batch: ScenarioBatch, config: MetricsConfig) -> np.ndarray:
    """(n,) str: the first criterion of success each row's plan fails (module docstring), "" where it succeeds."""
    human_end = batch.ego_xy_m[:, -1]
    start_x = batch.ego_xy_m[:, T0_INDEX, 0]
    markings = batch.marking_y_m
    end = _ends(frame["plan_xy_m"])
    same_lane = (lane_index(end[:, 1:2], markings)[:, 0] == lane_index(human_end[:, 1:2], markings)[:, 0]) | (
        np.abs(end[:, 1] - human_end[:, 1]) <= config.sr_lat_tol_m)
    progress, human = end[:, 0] - start_x, human_end[:, 0] - start_x
    tol = np.maximum(config.sr_progress_tol_m, config.sr_progress_tol_rel * np.abs(human))
    feasible = frame["feasible"].to_numpy(bool) if "feasible" in frame else np.ones(len(frame), bool)
    why = np.select([frame["success"].to_numpy(bool), frame["collision"].to_numpy(bool), ~same_lane,
                     progress < human - tol, progress > human + tol, ~feasible],
                    ["", "collision", "lane", "short", "long", "infeasible"], "other")
    return why


def _span(values: list[float]) -> list[float] | None:
    """[min, max] rounded to 0.01, or None without values."""
    return [round(min(values), 2), round(max(values), 2)] if values else None


def main(planner: str, reference: str, dirs: list[Path]) -> dict[str, object]:
    config = MetricsConfig()
    out: dict[str, object] = {}
    lost_why: Counter[str] = Counter()
    gained_ref_why: Counter[str] = Counter()
    lost_peaks: list[float] = []  # peak |a_lon| (m/s^2) of the infeasible plans among the lost / gained windows
    gained_peaks: list[float] = []
    lost_force: Counter[str] = Counter()
    gained_force: Counter[str] = Counter()
    cross: Counter[str] = Counter()
    force_all: Counter[str] = Counter()
    sr_by_force: dict[str, list[int]] = {}
    n = lost = gained = 0
    for d in dirs:
        p = paired_rows([d], planner, reference)
        a, b = p.planner, p.reference
        scenarios = load_scenarios(Path(json.loads((d / "run.json").read_text())["dataset"]["file"]))
        row_of = {str(x): i for i, x in enumerate(scenario_digests(scenarios))}
        rows = np.array([row_of[str(x)] for x in a["scenario_digest"]])
        batch = scenarios.take(rows)
        sa, sb = a["success"].to_numpy(bool), b["success"].to_numpy(bool)
        force = _in_force(a)
        why = _why(a, batch, config)
        lost_mask, gained_mask = sb & ~sa, sa & ~sb
        lost_why.update(why[lost_mask].tolist())
        ref_why = _why(b, batch, config)
        gained_ref_why.update(ref_why[gained_mask].tolist())
        for frame, m, peaks in ((a, lost_mask & (why == "infeasible"), lost_peaks),
                                (b, gained_mask & (ref_why == "infeasible"), gained_peaks)):
            if "peak_abs_acc_lon_mps2" in frame:
                peaks.extend(frame["peak_abs_acc_lon_mps2"].to_numpy(np.float64)[m].tolist())
        lost_force.update(force[lost_mask].tolist())
        gained_force.update(force[gained_mask].tolist())
        cross.update(f"{f}: {w}" for f, w in zip(force[lost_mask], why[lost_mask], strict=True))
        force_all.update(force.tolist())
        for f in np.unique(force):
            m = force == f
            acc = sr_by_force.setdefault(str(f), [0, 0, 0])
            acc[0] += int(m.sum())
            acc[1] += int(sa[m].sum())
            acc[2] += int(sb[m].sum())
        n += len(a)
        lost += int(lost_mask.sum())
        gained += int(gained_mask.sum())
    out.update({"windows": n, "lost": lost, "gained": gained, "lost_why": dict(lost_why),
                "gained_reference_why": dict(gained_ref_why),
                "infeasible_peak_acc_lon_mps2": {"lost": _span(lost_peaks), "gained_reference": _span(gained_peaks),
                                                 "limit": config.max_abs_acc_lon_mps2},
                "lost_in_force": dict(lost_force), "gained_in_force": dict(gained_force),
                "lost_in_force_why": dict(cross), "in_force_windows": dict(force_all),
                "sr_by_in_force": {f: {"windows": w, "sr_pct": round(100 * s / w, 1),
                                       "sr_ref_pct": round(100 * r / w, 1)} for f, (w, s, r) in sr_by_force.items()}})
    return out


if __name__ == "__main__":
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    print(json.dumps(main(sys.argv[1], sys.argv[2], [Path(a) for a in sys.argv[3:]]), indent=1))
