"""The trajectory diagram, ego frame, true to scale. gids: ``ego_past``, ``ego_truth``, ``plan:<name>``,
``nbr_past:<id>``, ``nbr_future:<id>``, ``nbr_box:<id>``, ``ego_box``, ``lane_line:<k>`` / ``road_edge:<k>``,
``goal``, ``adjusted_goal:<name>``."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle

from letspi.constants import T0_INDEX
from letspi.scenario.types import ScenarioBatch
from letspi.viz import style
from letspi.viz.data import ADJACENT_LANE, SAME_LANE, PlanTrack, neighbour_groups

GROUP_COLOURS = {SAME_LANE: style.NBR_SAME_LANE, ADJACENT_LANE: style.NBR_ADJACENT_LANE}
#: Marks on plans / ground truth: one per second of the horizon (frame 25, 50, ... after t = 0).
SECOND_MARKS = (24, 25)
#: A plan goal further than this from the predicted goal is drawn as an adjusted goal [m].
ADJUSTED_GOAL_TOL_M = 0.05


def group_colour(group: str | None) -> str:
    """Colour of a neighbour lane group (``letspi.viz.data``)."""
    return GROUP_COLOURS.get(group or "", style.NBR_OTHER)


def x_range_m(scenario: ScenarioBatch, tracks: Sequence[PlanTrack],
              goal_xy_m: np.ndarray | None) -> tuple[float, float]:
    """The relevant x range: the ego's past, ground truth, plans and goals, with a small margin."""
    xs = [np.asarray(scenario.ego_xy_m[0][:, 0], dtype=np.float64)]
    xs += [t.xy_m[:, 0] for t in tracks]
    xs += [t.goal_xy_m[:1] for t in tracks]
    if goal_xy_m is not None:
        xs.append(np.asarray(goal_xy_m, dtype=np.float64)[:1])
    allx = np.concatenate(xs)
    allx = allx[np.isfinite(allx)]
    lo, hi = (float(allx.min()), float(allx.max())) if allx.size else (-50.0, 150.0)
    span = max(hi - lo, 20.0)
    return lo - 0.04 * span - 3.0, hi + 0.04 * span + 3.0


def y_range_m(scenario: ScenarioBatch, tracks: Sequence[PlanTrack]) -> tuple[float, float]:
    """The road between its edges plus a margin (widened if a plan leaves the road)."""
    marks = np.asarray(scenario.marking_y_m[0], dtype=np.float64)
    marks = marks[np.isfinite(marks)]
    ys = [marks, np.asarray(scenario.ego_xy_m[0][:, 1], dtype=np.float64)] + [t.xy_m[:, 1] for t in tracks]
    ally = np.concatenate(ys)
    ally = ally[np.isfinite(ally)]
    lo, hi = (float(ally.min()), float(ally.max())) if ally.size else (-6.0, 6.0)
    return lo - 1.2, hi + 1.2


def _box(ax: Axes, xy: np.ndarray, vxy: np.ndarray, length: float, width: float, **kw: object) -> Rectangle:
    heading = float(np.degrees(np.arctan2(vxy[1], vxy[0]))) if np.all(np.isfinite(vxy)) and np.any(vxy) else 0.0
    rect = Rectangle(
        (float(xy[0]) - length / 2, float(xy[1]) - width / 2), length, width,
        angle=heading, rotation_point="center", **kw,  # type: ignore[arg-type]
    )
    ax.add_patch(rect)
    return rect


def draw_road(ax: Axes, scenario: ScenarioBatch) -> list[Line2D]:
    """Road surface between the edges, dashed crossable lane lines, solid road edges."""
    marks = np.asarray(scenario.marking_y_m[0], dtype=np.float64)
    edges = np.asarray(scenario.marking_is_edge[0], dtype=bool)
    ok = np.isfinite(marks)
    lines: list[Line2D] = []
    if ok.sum() >= 2:
        ax.axhspan(float(marks[ok].min()), float(marks[ok].max()), color=style.ROAD_FILL, zorder=0, lw=0)
    for k in np.flatnonzero(ok):
        is_edge = bool(edges[k])
        line = ax.axhline(
            float(marks[k]),
            color=style.ROAD_EDGE if is_edge else style.LANE_LINE,
            lw=1.6 if is_edge else 1.0,
            ls="-" if is_edge else (0, (6.0, 5.0)),
            zorder=1,
            gid=style.gid_marking(int(k), is_edge),
        )
        lines.append(line)
    return lines


def draw_trajectory(
    ax: Axes,
    scenario: ScenarioBatch,
    tracks: Sequence[PlanTrack],
    goal_xy_m: np.ndarray | None = None,
    *,
    colours: Sequence[str] | None = None,
    title: str | None = "Trajectory diagram",
) -> dict[str, Line2D]:
    """Draw the trajectory diagram of ``scenario`` into ``ax`` (aspect set to equal); ``tracks`` in legend order,
    ``colours`` one per track (default ``style.PLAN_COLOURS``). ``goal_xy_m`` (2,): the predicted goal; plan goals
    further than ``ADJUSTED_GOAL_TOL_M`` from it are drawn as adjusted goals. Returns the plan and ego lines by gid."""
    colours = list(colours) if colours is not None else [style.plan_colour(k) for k in range(len(tracks))]
    xlo, xhi = x_range_m(scenario, tracks, goal_xy_m)
    ylo, yhi = y_range_m(scenario, tracks)
    draw_road(ax, scenario)
    _draw_neighbours(ax, scenario, label_x_range_m=(xlo, xhi))
    out = _draw_ego(ax, scenario)
    out.update(_draw_plans_and_goals(ax, tracks, colours, goal_xy_m))

    ax.set_xlim(xlo, xhi)
    ax.set_ylim(ylo, yhi)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x, along travel [m]")
    ax.set_ylabel("y, left [m]")
    ax.grid(False)
    if title:
        ax.set_title(title, loc="left")
    return out


def _draw_neighbours(ax: Axes, scenario: ScenarioBatch, label_x_range_m: tuple[float, float]) -> None:
    """Neighbours: past solid, future dashed, box at t = 0, an id label when the box is in ``label_x_range_m``."""
    xlo, xhi = label_x_range_m
    groups = neighbour_groups(scenario)
    for j, group in enumerate(groups):
        if group is None:
            continue
        vid = int(scenario.nbr_id[0][j])
        xy = np.asarray(scenario.nbr_xy_m[0][j], dtype=np.float64)
        valid = np.asarray(scenario.nbr_valid[0][j], dtype=bool)
        colour = group_colour(group)
        past = np.where(valid[: T0_INDEX + 1, None], xy[: T0_INDEX + 1], np.nan)
        future = np.where(valid[T0_INDEX:, None], xy[T0_INDEX:], np.nan)
        ax.plot(past[:, 0], past[:, 1], color=colour, lw=1.4, zorder=3, gid=style.gid_nbr("past", vid))
        ax.plot(future[:, 0], future[:, 1], color=colour, lw=1.4, ls=style.TRUTH_STYLE, zorder=3,
                gid=style.gid_nbr("future", vid))
        if valid[T0_INDEX]:
            box_xy = xy[T0_INDEX]
            _box(ax, box_xy, np.asarray(scenario.nbr_vxy_mps[0][j, T0_INDEX], dtype=np.float64),
                 float(scenario.nbr_length_m[0][j]), float(scenario.nbr_width_m[0][j]),
                 facecolor=colour, edgecolor="black", lw=0.8, alpha=0.9, zorder=5, gid=style.gid_nbr("box", vid))
        else:  # not on the road at t = 0: no box, no label (the time-space diagram names it)
            continue
        if xlo <= box_xy[0] <= xhi:
            ax.annotate(
                f"{vid}", (float(box_xy[0]), float(box_xy[1]) + 0.5 * float(scenario.nbr_width_m[0][j])),
                xytext=(0, 2), textcoords="offset points", ha="center", va="bottom", fontsize=8,
                color="black", zorder=8, gid=f"nbr_label:{vid}", annotation_clip=True,
            )


def _draw_ego(ax: Axes, scenario: ScenarioBatch) -> dict[str, Line2D]:
    """The ego's past, ground truth and box at t = 0; its lines by gid (``ego_past``, ``ego_truth``)."""
    out: dict[str, Line2D] = {}
    ego = np.asarray(scenario.ego_xy_m[0], dtype=np.float64)
    out["ego_past"] = ax.plot(ego[: T0_INDEX + 1, 0], ego[: T0_INDEX + 1, 1], color=style.EGO_PAST, lw=2.0,
                              zorder=6, gid="ego_past")[0]
    out["ego_truth"] = ax.plot(ego[T0_INDEX:, 0], ego[T0_INDEX:, 1], color=style.EGO_TRUTH, lw=1.8,
                               ls=style.TRUTH_STYLE, marker="o", ms=3.5, mfc="white",
                               markevery=(25, 25), zorder=6, gid="ego_truth")[0]
    _box(ax, ego[T0_INDEX], np.asarray(scenario.ego_vxy_mps[0][T0_INDEX], dtype=np.float64),
         float(scenario.ego_length_m[0]), float(scenario.ego_width_m[0]),
         facecolor="white", edgecolor="black", lw=1.4, zorder=7, gid="ego_box")
    ax.annotate("ego", (float(ego[T0_INDEX, 0]), float(ego[T0_INDEX, 1]) - 0.5 * float(scenario.ego_width_m[0])),
                xytext=(0, -2), textcoords="offset points", ha="center", va="top", fontsize=8, fontweight="bold",
                zorder=8)
    return out


def _draw_plans_and_goals(ax: Axes, tracks: Sequence[PlanTrack], colours: Sequence[str],
                          goal_xy_m: np.ndarray | None) -> dict[str, Line2D]:
    """The plans (gid ``plan:<name>``), the predicted goal, and plan goals off it by > ``ADJUSTED_GOAL_TOL_M``."""
    out: dict[str, Line2D] = {}
    for track, colour in zip(tracks, colours, strict=True):
        out[style.gid_plan(track.name)] = ax.plot(
            track.xy_m[:, 0], track.xy_m[:, 1], color=colour, lw=2.2, marker="o", ms=3.5,
            markevery=SECOND_MARKS, zorder=7, gid=style.gid_plan(track.name), label=track.name,
        )[0]
    if goal_xy_m is not None and np.all(np.isfinite(goal_xy_m)):
        g = np.asarray(goal_xy_m, dtype=np.float64)
        ax.plot([g[0]], [g[1]], marker="*", ms=15, color=style.GOAL, mec="black", mew=0.7, ls="none",
                zorder=9, gid="goal")
        for track, colour in zip(tracks, colours, strict=True):
            a = track.goal_xy_m
            if np.all(np.isfinite(a)) and float(np.hypot(*(a - g))) > ADJUSTED_GOAL_TOL_M:
                ax.annotate("", xy=(float(a[0]), float(a[1])), xytext=(float(g[0]), float(g[1])),
                            arrowprops={"arrowstyle": "-|>", "color": colour, "lw": 1.3, "shrinkA": 6, "shrinkB": 5},
                            zorder=8)
                ax.plot([a[0]], [a[1]], marker="D", ms=8, color=colour, mec="black", mew=0.7, ls="none",
                        zorder=9, gid=f"adjusted_goal:{track.name}")
    return out


def role_legend_handles(track_names: Sequence[str], colours: Sequence[str], *, with_goals: bool = True,
                        adjusted: bool = False) -> list[Line2D]:
    """Legend proxies for every role of the trajectory and time-space diagrams."""
    h = [
        Line2D([], [], color=style.EGO_PAST, lw=2.0, label="ego past"),
        Line2D([], [], color=style.EGO_TRUTH, lw=1.8, ls=style.TRUTH_STYLE, marker="o", ms=3.5, mfc="white",
               label="ego ground truth"),
    ]
    h += [Line2D([], [], color=c, lw=2.2, marker="o", ms=3.5, label=f"plan: {n}")
          for n, c in zip(track_names, colours, strict=True)]
    h += [
        Line2D([], [], color=style.NBR_SAME_LANE, lw=1.4, label="neighbour, same lane"),
        Line2D([], [], color=style.NBR_ADJACENT_LANE, lw=1.4, label="neighbour, adjacent lane"),
        Line2D([], [], color=style.NBR_OTHER, lw=1.4, label="neighbour, other lane"),
        Line2D([], [], color="#555555", lw=1.4, ls=style.TRUTH_STYLE, label="(dashed: recorded future)"),
    ]
    if with_goals:
        h.append(Line2D([], [], marker="*", ms=12, color=style.GOAL, mec="black", ls="none", label="predicted goal"))
    if adjusted:
        h.append(Line2D([], [], marker="D", ms=7, color="white", mec="black", ls="none",
                        label="goal used by a plan (adjusted)"))
    return h
