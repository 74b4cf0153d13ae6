"""The closed-loop panel: the same scenario open loop and closed loop, one above the other (from arrays only; closed
loop with every replan's plan; y axis stretched). Artist gids: ``ego_path:<row>``, ``plan:<row>:<r>``,
``replan:<row>``, ``nbr_path:<row>:<j>``, ``collision:<row>``, ``road_edge:<k>`` / ``lane_line:<k>``."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from letspi.viz import style


@dataclass(frozen=True)
class LoopOutcome:
    """One row of the panel (ego frame; F future frames, N neighbours, R plans): ``label``; ``ego_xy_m`` (F, 2) (the
    plan itself in open loop); ``nbr_xy_m`` (N, F, 2), NaN where absent, and ``nbr_valid`` (N, F); ``plans_xy_m`` (R,
    F, 2) made at ``replan_step`` (R,) frames after t = 0; ``collision_step``, ``collision_nbr`` (-1: none);
    ``notes``, short metric lines ({"CR": "yes", "min TTC": "1.2 s"})."""

    label: str
    ego_xy_m: np.ndarray
    nbr_xy_m: np.ndarray
    nbr_valid: np.ndarray
    plans_xy_m: np.ndarray
    replan_step: np.ndarray
    collision_step: int = -1
    collision_nbr: int = -1
    notes: Mapping[str, str] = field(default_factory=dict)


def _box(ax: Axes, centre: np.ndarray, length: float, width: float, gid: str, colour: str) -> None:
    ax.add_patch(Rectangle((float(centre[0]) - length / 2, float(centre[1]) - width / 2), length, width,
                           facecolor=colour, edgecolor="black", lw=0.8, alpha=0.85, zorder=6, gid=gid))


def _draw_row(ax: Axes, row: int, out: LoopOutcome, marking_y_m: np.ndarray, marking_is_edge: np.ndarray,
              ego_size_m: tuple[float, float], nbr_size_m: np.ndarray) -> None:
    marks = np.asarray(marking_y_m, dtype=np.float64)
    ok = np.isfinite(marks)
    if ok.sum() >= 2:
        ax.axhspan(float(marks[ok].min()), float(marks[ok].max()), color=style.ROAD_FILL, zorder=0, lw=0)
    for k in np.flatnonzero(ok):
        edge = bool(marking_is_edge[k])
        ax.axhline(float(marks[k]), color=style.ROAD_EDGE if edge else style.LANE_LINE, lw=1.6 if edge else 1.0,
                   ls="-" if edge else (0, (6.0, 5.0)), zorder=1, gid=style.gid_marking(int(k), edge))
    nbr_xy = np.asarray(out.nbr_xy_m, dtype=np.float64)
    valid = np.asarray(out.nbr_valid, dtype=bool)
    for j in range(nbr_xy.shape[0]):
        if not valid[j].any():
            continue
        path = np.where(valid[j, :, None], nbr_xy[j], np.nan)
        ax.plot(path[:, 0], path[:, 1], color=style.NBR_OTHER, lw=1.3, zorder=3, gid=f"nbr_path:{row}:{j}")
        first = int(np.flatnonzero(valid[j])[0])
        ax.plot(*path[first], marker="o", ms=3.5, color=style.NBR_OTHER, zorder=4)
    plans = np.asarray(out.plans_xy_m, dtype=np.float64)
    steps = np.asarray(out.replan_step, dtype=np.int64)
    for r in range(plans.shape[0]):
        colour = style.plan_colour(r)
        ax.plot(plans[r, :, 0], plans[r, :, 1], color=colour, lw=1.2, alpha=0.95, zorder=5, gid=f"plan:{row}:{r}",
                label=f"plan at t = {steps[r] * 0.04:.1f} s")
    ego = np.asarray(out.ego_xy_m, dtype=np.float64)
    ax.plot(ego[:, 0], ego[:, 1], color=style.EGO_PAST, lw=3.0, zorder=4, gid=f"ego_path:{row}", label="ego")
    starts = np.array([[0.0, 0.0]] + [ego[s - 1] for s in steps[1:] if 0 < s <= len(ego)])
    ax.plot(starts[:, 0], starts[:, 1], ls="none", marker="D", ms=5, color="black", zorder=7, gid=f"replan:{row}")
    if out.collision_step >= 0:
        s = int(out.collision_step)
        _box(ax, ego[s], *ego_size_m, f"collision_ego:{row}", style.ALERT)
        if out.collision_nbr >= 0:
            j = int(out.collision_nbr)
            _box(ax, nbr_xy[j, s], float(nbr_size_m[j, 0]), float(nbr_size_m[j, 1]), f"collision_nbr:{row}",
                 style.NBR_SAME_LANE)
        ax.plot(*ego[s], marker="X", ms=11, color=style.ALERT, mec="black", zorder=8, gid=f"collision:{row}")
    text = "\n".join(f"{k}: {v}" for k, v in out.notes.items())
    if text:
        ax.text(0.995, 0.96, text, transform=ax.transAxes, ha="right", va="top", fontsize=8,
                bbox={"facecolor": style.TEXT_BOX_FACE, "edgecolor": "#BBBBBB", "lw": 0.6}, zorder=9)
    ax.set_title(out.label, loc="left")
    ax.set_ylabel("y [m] (stretched)")


def plot_closed_loop_panel(
    open_loop: LoopOutcome,
    closed_loop: LoopOutcome,
    *,
    marking_y_m: np.ndarray,
    marking_is_edge: np.ndarray,
    ego_length_m: float,
    ego_width_m: float,
    nbr_length_m: np.ndarray,
    nbr_width_m: np.ndarray,
    title: str = "",
) -> Figure:
    """Two rows (open loop above, closed loop below) with shared axes; returns the figure. marking_y_m,
    marking_is_edge: (M,); ego_length_m, ego_width_m [m]; nbr_length_m, nbr_width_m: (N,) [m]."""
    sizes = np.stack([np.asarray(nbr_length_m, float), np.asarray(nbr_width_m, float)], axis=-1)
    with style.letspi_style():
        fig = Figure(figsize=(11.0, 6.0))
        axes = fig.subplots(2, 1, sharex=True, sharey=True)
        for row, (ax, out) in enumerate(zip(axes, (open_loop, closed_loop), strict=True)):
            _draw_row(ax, row, out, marking_y_m, marking_is_edge, (ego_length_m, ego_width_m), sizes)
        rows = (open_loop, closed_loop)
        xs = np.concatenate([np.asarray(o.ego_xy_m)[:, 0] for o in rows] + [[0.0]])
        xs = xs[np.isfinite(xs)]
        # neighbours within 60 m of the ego's range are shown whole
        nx = np.concatenate([np.asarray(o.nbr_xy_m)[..., 0][np.asarray(o.nbr_valid, bool)] for o in rows])
        nx = nx[np.isfinite(nx) & (nx > xs.min() - 60.0) & (nx < xs.max() + 60.0)]
        xs = np.concatenate([xs, nx])
        span = max(float(xs.max() - xs.min()), 20.0)
        axes[0].set_xlim(float(xs.min()) - 0.08 * span, float(xs.max()) + 0.05 * span)
        marks = np.asarray(marking_y_m, dtype=np.float64)
        marks = marks[np.isfinite(marks)]
        if marks.size:
            axes[0].set_ylim(float(marks.min()) - 1.5, float(marks.max()) + 1.5)
        axes[1].set_xlabel("x [m] (ego frame at t = 0)")
        axes[1].legend(loc="lower left", ncol=6, fontsize=7)
        if title:
            fig.suptitle(title)
    return fig
