"""``plot_scenario``: the paper's Figs 4-5 for one scenario. Top to bottom: the trajectory diagram; the
time-space diagram beside the gap to the preceding vehicle; one text row per reflection iteration; one legend."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from letspi.physics.goals import KinematicGoalPredictor
from letspi.planners.base import PlanBatch
from letspi.scenario.types import ScenarioBatch
from letspi.viz import style
from letspi.viz.data import PlanTrack, plan_tracks
from letspi.viz.llm_panel import IterationRecord, chars_per_line, draw_iteration, iterations_height_in
from letspi.viz.time_space import draw_gap, draw_time_space
from letspi.viz.trajectory import ADJUSTED_GOAL_TOL_M, draw_trajectory, role_legend_handles, x_range_m, y_range_m

DEFAULT_WIDTH_IN = 15.0
_TS_ROW_IN = 3.6
_TRAJ_EXTRA_IN = 1.0  # axis labels and title around the equal-aspect road strip


def predicted_goal(batch: ScenarioBatch, index: int) -> np.ndarray:
    """The unadjusted goal of scenario ``index`` (``KinematicGoalPredictor``'s top goal), (2,)."""
    return np.asarray(KinematicGoalPredictor().predict_goals(batch.take([index])).top[0], dtype=np.float64)


def _has_adjusted(tracks: Sequence[PlanTrack], goal: np.ndarray | None) -> bool:
    if goal is None or not np.all(np.isfinite(goal)):
        return False
    return any(np.all(np.isfinite(t.goal_xy_m)) and float(np.hypot(*(t.goal_xy_m - goal))) > ADJUSTED_GOAL_TOL_M
               for t in tracks)


def _row_heights_in(scenario: ScenarioBatch, tracks: Sequence[PlanTrack], goal: np.ndarray | None,
                    records: Sequence[IterationRecord], width_in: float) -> tuple[list[float], int]:
    """Heights [in] of the figure's rows (road to scale, time-space row, one text row per iteration)
    and the characters per line of a text panel."""
    xlo, xhi = x_range_m(scenario, tracks, goal)
    ylo, yhi = y_range_m(scenario, tracks)
    traj_h = (width_in - 1.0) * (yhi - ylo) / (xhi - xlo) + _TRAJ_EXTRA_IN
    width_chars = chars_per_line(width_in / 2.0 - 0.2)
    return [traj_h, _TS_ROW_IN, *iterations_height_in(records, width_chars)], width_chars


def _default_title(scenario: ScenarioBatch) -> str:
    speed = float(np.hypot(*scenario.ego_vxy_mps[0][len(scenario.ego_vxy_mps[0]) - 126]))
    return (f"Scenario {scenario.scenario_id[0]} (recording {int(scenario.recording_id[0])}, ego "
            f"{int(scenario.ego_id[0])}, {speed * 3.6:.0f} km/h at t = 0)")


def plot_scenario(
    batch: ScenarioBatch,
    index: int,
    plans: Mapping[str, PlanBatch] | None = None,
    iterations: Sequence[IterationRecord] | None = None,
    out_png: Path | str | None = None,
    *,
    goal_xy_m: np.ndarray | None = None,
    title: str | None = None,
    width_in: float = DEFAULT_WIDTH_IN,
) -> Figure:
    """Draw scenario ``index`` of ``batch`` with ``plans`` (name -> ``PlanBatch`` of that scenario alone or of the
    whole batch, in ``style.PLAN_COLOURS`` order) and an LLM planner's reflection ``iterations`` (a text row each).
    ``out_png``: also saved there; ``goal_xy_m`` (2,): the unadjusted goal (default ``KinematicGoalPredictor``'s);
    ``title`` default: the scenario and its recording; ``width_in`` [in]. Axes are labelled ``trajectory``,
    ``time_space``, ``gap``, ``safety_report:<k>``, ``response:<k>``."""
    if not 0 <= index < len(batch):
        raise IndexError(f"scenario index {index} outside 0..{len(batch) - 1}")
    scenario = batch.take([index])
    tracks = plan_tracks(plans, index, len(batch))
    colours = [style.plan_colour(k) for k in range(len(tracks))]
    goal = predicted_goal(batch, index) if goal_xy_m is None else np.asarray(goal_xy_m, dtype=np.float64)
    records = sorted(iterations or [], key=lambda r: r.iteration)

    heights, width_chars = _row_heights_in(scenario, tracks, goal, records, width_in)
    legend_h = 0.9
    with style.letspi_style():
        fig = Figure(figsize=(width_in, sum(heights) + legend_h + 0.5), layout="constrained")
        grid = fig.add_gridspec(len(heights), 2, height_ratios=heights)
        ax_traj = fig.add_subplot(grid[0, :], label="trajectory")
        ax_ts = fig.add_subplot(grid[1, 0], label="time_space")
        ax_gap = fig.add_subplot(grid[1, 1], label="gap", sharex=ax_ts)
        draw_trajectory(ax_traj, scenario, tracks, goal, colours=colours)
        draw_time_space(ax_ts, scenario, tracks, colours=colours)
        draw_gap(ax_gap, scenario, tracks, colours=colours)
        for row, record in enumerate(records, start=2):
            ax_l = fig.add_subplot(grid[row, 0], label=f"safety_report:{record.iteration}")
            ax_r = fig.add_subplot(grid[row, 1], label=f"response:{record.iteration}")
            draw_iteration(ax_l, ax_r, record, width_chars, n_iterations=len(records))
        handles = role_legend_handles([t.name for t in tracks], colours, with_goals=goal is not None,
                                      adjusted=_has_adjusted(tracks, goal))
        fig.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 6), frameon=False)
        fig.suptitle(title or _default_title(scenario), fontsize=style.BASE_FONT_SIZE + 3, fontweight="bold")
        if out_png is not None:
            _save_png(fig, Path(out_png))
    return fig


def _save_png(fig: Figure, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
