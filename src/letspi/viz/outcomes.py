"""Panel rows (``LoopOutcome``) from stored results: ``stored_outcome`` (what was scored) and ``first_plan_outcome``
(a closed-loop row's plan made at t = 0, i.e. the open-loop plan, scored on the spot)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from letspi.assembly.planners import BuiltPlanner
from letspi.constants import DT_S, N_FUTURE, T0_INDEX
from letspi.evaluation.closed_loop import CL_PLAN_XY, closed_loop_row
from letspi.metrics.compute import compute_metrics
from letspi.metrics.config import MetricsConfig
from letspi.scenario.types import ScenarioBatch
from letspi.simulation import ClosedLoopChunk, ClosedLoopConfig, chunk_metrics, run_closed_loop
from letspi.viz.closed_loop import LoopOutcome, plot_closed_loop_panel


def _yes(value: object) -> str:
    return "yes" if bool(value) else "no"


def _num(value: object, unit: str) -> str:
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return "n/a"
    return "∞" if math.isinf(v) else ("n/a" if math.isnan(v) else f"{v:.2f} {unit}")


def row_notes(rec: Mapping[str, Any]) -> dict[str, str]:
    """Short metric lines of a stored row for the panel."""
    notes = {"collision": _yes(rec.get("collision"))}
    if rec.get("collision"):
        notes["at fault"] = _yes(rec.get("collision_at_fault"))
    if "sumo_collision" in rec:
        notes["SUMO collision"] = _yes(rec.get("sumo_collision"))
    notes["min TTC"] = _num(rec.get("min_ttc_s"), "s")
    notes["min gap"] = _num(rec.get("min_box_gap_m"), "m")
    return notes


def _log_neighbours(scenario: ScenarioBatch) -> tuple[np.ndarray, np.ndarray]:
    fut = slice(T0_INDEX + 1, T0_INDEX + 1 + N_FUTURE)
    return np.asarray(scenario.nbr_xy_m[0][:, fut], np.float64), np.asarray(scenario.nbr_valid[0][:, fut], bool)


def stored_outcome(label: str, scenario: ScenarioBatch, rec: Mapping[str, Any]) -> LoopOutcome:
    """A stored row (``load_planner_results(..., with_plans=True)``) of ``scenario`` (a 1-batch) as a panel row."""
    step, nbr = int(rec.get("collision_step", -1)), int(rec.get("collision_nbr", -1))
    if CL_PLAN_XY in rec and rec[CL_PLAN_XY] is not None:
        cl = closed_loop_row(rec)
        return LoopOutcome(label, cl.ego_xy_m, cl.nbr_xy_m, cl.nbr_valid, cl.plans_xy_m, cl.replan_step, step, nbr,
                           row_notes(rec))
    xy = np.asarray(rec["plan_xy_m"], np.float64).reshape(N_FUTURE, 2)
    nbr_xy, valid = _log_neighbours(scenario)
    return LoopOutcome(label, xy, nbr_xy, valid, xy[None], np.array([0]), step, nbr, row_notes(rec))


def first_plan_outcome(scenario: ScenarioBatch, rec: Mapping[str, Any], config: MetricsConfig | None = None,
                       label: str = "open loop: the plan made at t = 0, recorded neighbours") -> LoopOutcome:
    """The t = 0 plan of a closed-loop row scored here against the log (velocities: the plan's finite differences)."""
    cl = closed_loop_row(rec)
    xy = cl.plans_xy_m[0]
    vxy = np.diff(np.concatenate([np.zeros((1, 2)), xy]), axis=0) / DT_S  # ego frame: the ego is at 0 at t = 0
    m = compute_metrics(scenario, xy[None], vxy[None], cl.plan_goals_xy_m[:1], config)
    row = {k: m[k][0] for k in ("collision", "collision_at_fault", "min_ttc_s", "min_box_gap_m")}
    nbr_xy, valid = _log_neighbours(scenario)
    return LoopOutcome(label, xy, nbr_xy, valid, xy[None], np.array([0]), int(m["collision_step"][0]),
                       int(m["collision_nbr"][0]), row_notes(row))


def panel(scenario: ScenarioBatch, top: LoopOutcome, bottom: LoopOutcome, title: str = "") -> Figure:
    """``plot_closed_loop_panel`` with the scenario's road and vehicle sizes."""
    return plot_closed_loop_panel(
        top, bottom, marking_y_m=scenario.marking_y_m[0], marking_is_edge=scenario.marking_is_edge[0],
        ego_length_m=float(scenario.ego_length_m[0]), ego_width_m=float(scenario.ego_width_m[0]),
        nbr_length_m=scenario.nbr_length_m[0], nbr_width_m=scenario.nbr_width_m[0], title=title)


def closed_loop_report_figure(scenario: ScenarioBatch, rec: Mapping[str, Any], name: str, mode: str) -> Figure:
    """The report's picture of a closed-loop row: its t = 0 plan in open loop above, the run below."""
    return panel(scenario, first_plan_outcome(scenario, rec), stored_outcome(mode, scenario, rec),
                 title=f"{name}: scenario {rec.get('scenario_id')}")


def simulate_panel(scenario: ScenarioBatch, built: BuiltPlanner, closed: ClosedLoopConfig,
                   config: MetricsConfig | None = None, scripted_nbr: np.ndarray | None = None) -> Figure:
    """Simulate one scenario (a 1-batch) closed loop in this process and draw the panel (``letspi plot --mode``);
    ``scripted_nbr`` (1, N): neighbours that keep their log in ``closed-loop-hybrid``."""
    seen = scenario if built.reads_future else scenario.history()
    plan = built.planner.plan(seen)
    m = compute_metrics(scenario, plan.xy_m, plan.vxy_mps, plan.goals_xy_m, config)
    open_rec = {k: m[k][0] for k in ("collision", "collision_at_fault", "min_ttc_s", "min_box_gap_m",
                                     "collision_step", "collision_nbr")}
    open_rec["plan_xy_m"] = plan.xy_m[0]
    chunk = ClosedLoopChunk.concat(list(run_closed_loop(built, scenario, closed, scripted_nbr=scripted_nbr)))
    cm = chunk_metrics(scenario, chunk, config)
    notes = row_notes({**{k: cm[k][0] for k in ("collision", "collision_at_fault", "min_ttc_s", "min_box_gap_m")},
                       "sumo_collision": chunk.sumo_collision[0]})
    outcome = LoopOutcome(f"{closed.mode.value} (replanning every {closed.replan_s_of(built.name):g} s)",
                          chunk.ego_xy_m[0], chunk.nbr_xy_m[0], chunk.nbr_valid[0], chunk.plan_xy_m[0],
                          chunk.replan_step, int(cm["collision_step"][0]), int(cm["collision_nbr"][0]), notes)
    top = stored_outcome("open loop (recorded neighbours)", scenario, open_rec)
    return panel(scenario, top, outcome, title=f"{built.name}: scenario {scenario.scenario_id[0]}")
