"""The time-space diagram: x(t) of the ego, its plans and the neighbours, and the gap to the preceding vehicle (the
line breaks where the leader changes). gids: ``ts:ego_past``, ``ts:ego_truth``, ``ts:plan:<name>``, ``ts:nbr:<id>``,
``gap:truth``, ``gap:plan:<name>``."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.lines import Line2D

from letspi.constants import N_TOTAL, T0_INDEX
from letspi.scenario.types import ScenarioBatch
from letspi.viz import style
from letspi.viz.data import PlanTrack, neighbour_groups, preceding_gap, times_s
from letspi.viz.trajectory import SECOND_MARKS, group_colour

#: neighbours whose x never comes closer than this to the ego's x range are left out [m]
NEIGHBOUR_MARGIN_M = 40.0


def draw_time_space(
    ax: Axes,
    scenario: ScenarioBatch,
    tracks: Sequence[PlanTrack],
    *,
    colours: Sequence[str] | None = None,
    title: str | None = "Time-space diagram",
) -> dict[str, Line2D]:
    """Longitudinal position [m] over time [s] of the ego and the neighbours; returns lines by gid."""
    colours = list(colours) if colours is not None else [style.plan_colour(k) for k in range(len(tracks))]
    t = times_s()
    ego = np.asarray(scenario.ego_xy_m[0], dtype=np.float64)
    out: dict[str, Line2D] = {}
    ego_x = np.concatenate([ego[:, 0]] + [tr.xy_m[:, 0] for tr in tracks])
    ego_x = ego_x[np.isfinite(ego_x)]
    lo, hi = float(ego_x.min()) - NEIGHBOUR_MARGIN_M, float(ego_x.max()) + NEIGHBOUR_MARGIN_M
    for j, group in enumerate(neighbour_groups(scenario)):
        if group is None:
            continue
        vid = int(scenario.nbr_id[0][j])
        valid = np.asarray(scenario.nbr_valid[0][j], dtype=bool)
        x = np.where(valid, np.asarray(scenario.nbr_xy_m[0][j, :, 0], dtype=np.float64), np.nan)
        if not np.any((x >= lo) & (x <= hi)):
            continue
        colour = group_colour(group)
        past = np.where(np.arange(N_TOTAL) <= T0_INDEX, x, np.nan)
        future = np.where(np.arange(N_TOTAL) >= T0_INDEX, x, np.nan)
        ax.plot(t, past, color=colour, lw=1.3, zorder=3)
        out[f"ts:nbr:{vid}"] = ax.plot(t, future, color=colour, lw=1.3, ls=style.TRUTH_STYLE, zorder=3,
                                       gid=f"ts:nbr:{vid}")[0]
        inside = np.flatnonzero(np.isfinite(x) & (x >= lo) & (x <= hi))
        last = int(inside[-1])
        at_end = last == N_TOTAL - 1
        ax.annotate(str(vid), (float(t[last]), float(x[last])), xytext=(3, 0) if at_end else (0, -3),
                    textcoords="offset points", fontsize=8, va="center" if at_end else "top",
                    ha="left" if at_end else "right", color="black", annotation_clip=False)
    out["ts:ego_past"] = ax.plot(t[: T0_INDEX + 1], ego[: T0_INDEX + 1, 0], color=style.EGO_PAST, lw=2.0,
                                 zorder=6, gid="ts:ego_past")[0]
    out["ts:ego_truth"] = ax.plot(t[T0_INDEX:], ego[T0_INDEX:, 0], color=style.EGO_TRUTH, lw=1.8,
                                  ls=style.TRUTH_STYLE, marker="o", ms=3.5, mfc="white", markevery=(25, 25),
                                  zorder=6, gid="ts:ego_truth")[0]
    for track, colour in zip(tracks, colours, strict=True):
        gid = "ts:" + style.gid_plan(track.name)
        out[gid] = ax.plot(track.t_s, track.xy_m[:, 0], color=colour, lw=2.2, marker="o", ms=3.5,
                           markevery=SECOND_MARKS, zorder=7, gid=gid)[0]
    ax.axvline(0.0, color="#777777", lw=0.8, zorder=1)
    ax.set_ylim(lo, hi)
    ax.set_xlim(float(t[0]), float(t[-1]) + 0.45)  # room for the id labels at the right end
    ax.set_xlabel("time t [s] (0 = planning instant)")
    ax.set_ylabel("x, along travel [m]")
    if title:
        ax.set_title(title, loc="left")
    return out


def draw_gap(
    ax: Axes,
    scenario: ScenarioBatch,
    tracks: Sequence[PlanTrack],
    *,
    colours: Sequence[str] | None = None,
    title: str | None = "Gap to the preceding vehicle",
) -> dict[str, Line2D]:
    """Bumper-to-bumper gap [m] to the vehicle ahead in the ego's lane over time [s]."""
    colours = list(colours) if colours is not None else [style.plan_colour(k) for k in range(len(tracks))]
    t = times_s()
    ego = np.asarray(scenario.ego_xy_m[0], dtype=np.float64)
    out: dict[str, Line2D] = {}
    gap_truth, slot_truth = preceding_gap(scenario, ego, np.arange(N_TOTAL))
    future_min = _min_label(gap_truth[T0_INDEX + 1 :])
    out["gap:truth"] = ax.plot(*_break_at_leader_change(t, gap_truth, slot_truth), color=style.EGO_TRUTH, lw=1.8,
                               ls=style.TRUTH_STYLE,
                               label=f"ground truth{future_min}", gid="gap:truth")[0]
    any_finite = bool(np.isfinite(gap_truth).any())
    frames = np.arange(T0_INDEX + 1, N_TOTAL)
    for track, colour in zip(tracks, colours, strict=True):
        n = min(len(track.xy_m), len(frames))
        gap, slot = preceding_gap(scenario, track.xy_m[:n], frames[:n])
        any_finite |= bool(np.isfinite(gap).any())
        gid = "gap:" + style.gid_plan(track.name)
        out[gid] = ax.plot(*_break_at_leader_change(track.t_s[:n], gap, slot), color=colour, lw=2.2,
                           label=f"{track.name}{_min_label(gap)}",
                           gid=gid)[0]
    ax.axhline(0.0, color=style.ALERT, lw=1.0, ls=":", zorder=1)
    ax.axvline(0.0, color="#777777", lw=0.8, zorder=1)
    ax.set_xlim(float(t[0]), float(t[-1]) + 0.45)
    ax.set_xlabel("time t [s] (0 = planning instant)")
    ax.set_ylabel("gap to preceding vehicle [m]")
    if any_finite:
        bottom, top = ax.get_ylim()
        ax.set_ylim(min(bottom, -1.0), top)
        ax.legend(loc="best", title="min gap after t = 0", title_fontsize=8)
    else:
        ax.set_ylim(-1.0, 10.0)
        ax.text(0.5, 0.5, "no vehicle ahead in the ego's lane", transform=ax.transAxes, ha="center",
                va="center", color="#555555")
    if title:
        ax.set_title(title, loc="left")
    return out


def _break_at_leader_change(t: np.ndarray, gap: np.ndarray, slot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Insert a NaN where the preceding vehicle changes, so no vertical jump line is drawn."""
    change = np.flatnonzero(slot[1:] != slot[:-1]) + 1
    return np.insert(t, change, np.nan), np.insert(gap, change, np.nan)


def _min_label(gap: np.ndarray) -> str:
    finite = gap[np.isfinite(gap)]
    return f" (min {finite.min():.1f} m)" if finite.size else " (no leader)"
