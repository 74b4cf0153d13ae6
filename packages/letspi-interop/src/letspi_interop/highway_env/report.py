"""Drawings of highway-env episodes and the HTML report of a highway-env results directory.

``episode_figure``: one stored episode, drawn from what was recorded (never re-simulated): above, the road seen
from above (x along the road, y to the left; lanes of the ``RoadLayout``) with the ego's track, every
``plan_every``-th plan it followed, the other vehicles that came within ``near_m`` of the ego, and the first
collision marked; below, the ego's speed over time with the speed of each drawn plan.

``write_episode_report(dir)``: ``report.html`` with the table of ``metrics.json`` (95 % intervals), the paired
comparison with the reference, the timing, and per label one episode drawn: its first failure (shortest survival),
else its first seed.
"""

from __future__ import annotations

import html
import json
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from letspi.constants import DT_S
from letspi.fsutil import atomic_write_text
from letspi.metrics.aggregate import format_with_interval, paired_rows
from letspi.viz.report import figure_to_data_uri
from letspi_interop.highway_env.scene import EpisodeTracks, RoadLayout
from letspi_interop.highway_env.settings import RUN_MODE
from letspi_interop.highway_env.store import PAIRED, SEED_COLUMN, TABLE, labels, load_episode, load_episodes


def episode_figure(tracks: EpisodeTracks, road: RoadLayout, plan_t_s: np.ndarray, plans_xy_m: np.ndarray, *,
                   title: str = "", plan_every: int = 5, near_m: float = 60.0) -> Figure:
    """The episode (module doc): plans_xy_m (R, F, 2) in highway-env coordinates, made at plan_t_s (R,)."""
    fig = Figure(figsize=(11, 6.2))
    top, bottom = fig.subplots(2, 1, gridspec_kw={"height_ratios": [1.3, 1]})
    e = tracks.ego
    ego = tracks.xy_m[e]
    for m_y in road.markings_y_m:
        top.axhline(-m_y, color="0.3", lw=1.2 if m_y in (road.markings_y_m[0], road.markings_y_m[-1]) else 0.6,
                    ls="-" if m_y in (road.markings_y_m[0], road.markings_y_m[-1]) else "--")
    dist = np.hypot(*(tracks.xy_m - ego[None]).transpose(2, 0, 1))
    for row in np.flatnonzero((dist.min(axis=1) < near_m) & (np.arange(len(tracks.ids)) != e)):
        close = dist[row] < near_m
        top.plot(np.where(close, tracks.xy_m[row, :, 0], np.nan), -np.where(close, tracks.xy_m[row, :, 1], np.nan),
                 color="0.6", lw=0.8)
    shown = np.arange(0, len(plan_t_s), max(plan_every, 1))
    for r in shown:
        top.plot(plans_xy_m[r, :, 0], -plans_xy_m[r, :, 1], color="tab:orange", lw=0.7, alpha=0.6)
    top.plot(ego[:, 0], -ego[:, 1], color="tab:blue", lw=2.0, label="ego")
    crash = np.flatnonzero(tracks.crashed[e])
    if len(crash):
        top.plot(*(ego[crash[0]] * [1, -1]), "x", color="red", ms=12, mew=2.5, label="first collision")
    top.set_xlabel("x along the road [m]")
    top.set_ylabel("y, left of travel [m]")
    top.legend(loc="upper right", fontsize=8)
    top.set_title(title, fontsize=10)
    t = tracks.t_s - tracks.t_s[0]
    bottom.plot(t, np.hypot(*tracks.vxy_mps[e].T), color="tab:blue", lw=2.0, label="ego")
    for r in shown:
        v = np.hypot(*np.gradient(plans_xy_m[r], DT_S, axis=0).T)
        bottom.plot(plan_t_s[r] - tracks.t_s[0] + DT_S * np.arange(1, len(v) + 1), v, color="tab:orange", lw=0.7,
                    alpha=0.6)
    bottom.set_xlabel("time [s]")
    bottom.set_ylabel("speed [m/s]")
    if len(shown):
        bottom.plot([], [], color="tab:orange", lw=0.7, label=f"plans (every {plan_every}th)")
    bottom.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    return fig


def is_highway_env_dir(directory: Path | str) -> bool:
    """Whether ``directory`` holds highway-env episodes (its ``run.json`` says so)."""
    run = Path(directory) / "run.json"
    return run.is_file() and json.loads(run.read_text()).get("identity", {}).get("mode") == RUN_MODE


def report_if_highway_env(directory: Path, out: Path | None) -> Path | None:
    """The ``letspi.reports`` entry point: ``report.html`` of a highway-env directory, else None."""
    return write_episode_report(directory, out) if is_highway_env_dir(directory) else None


def _shown_seed(frame: Any) -> int:
    """The seed drawn for a label: its shortest failed episode, else its first."""
    failed = frame[~frame["success"].astype(bool)]
    pick = failed.sort_values(["survival_s", SEED_COLUMN]) if len(failed) else frame
    return int(pick[SEED_COLUMN].iloc[0])


def _table(record: dict[str, Any]) -> str:
    head = "".join(f"<th>{html.escape(label)}</th>" for label, _ in TABLE)
    rows = []
    for name, agg in record["planners"].items():
        own = record["intervals"].get(name, {})
        cells = "".join(f"<td>{html.escape(format_with_interval(agg.get(k), own.get(k)))}</td>" for _, k in TABLE)
        rows.append(f"<tr><td>{html.escape(name)}</td><td>{agg['n']}</td>{cells}</tr>")
    return f"<table><tr><th>planner</th><th>n</th>{head}</tr>{''.join(rows)}</table>"


def _paired(record: dict[str, Any]) -> str:
    paired = record.get("paired")
    if not paired:
        return ""
    ref = html.escape(str(paired["reference"]))
    rows = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>"
                   for r in paired_rows(paired, PAIRED))
    return (f"<h2>Paired with {ref} (same seeds)</h2><table><tr><th>planner</th><th>metric</th><th>n</th>"
            f"<th>Δ (95 % CI)</th><th>only planner</th><th>only {ref}</th><th>both</th><th>p (McNemar)</th></tr>"
            f"{rows}</table>")


def write_episode_report(out_dir: Path | str, out_html: Path | str | None = None, *, plan_every: int = 5) -> Path:
    """``report.html`` of a highway-env results directory (module doc); returns its path."""
    out_dir = Path(out_dir)
    target = Path(out_html) if out_html is not None else out_dir / "report.html"
    record = json.loads((out_dir / "metrics.json").read_text())
    env = record["run"]["identity"]["environment"]
    sections = []
    for name in labels(out_dir):
        frame = load_episodes(out_dir, name)
        if not len(frame):
            continue
        seed = _shown_seed(frame)
        tracks, road, plan_t, plans = load_episode(out_dir, name, seed)
        row = frame[frame[SEED_COLUMN] == seed].iloc[0]
        title = (f"{name}, seed {seed}: {'success' if row['success'] else 'failure'} after {row['survival_s']:.1f} s"
                 f"{', at fault' if row['at_fault'] else ''}; mean speed {row['mean_speed_mps']:.1f} m/s")
        uri = figure_to_data_uri(episode_figure(tracks, road, plan_t, plans, title=title, plan_every=plan_every))
        sections.append(f"<h3>{html.escape(title)}</h3><img src='{uri}' style='max-width:100%'>")
    page = (f"<!doctype html><html><head><meta charset='utf-8'><title>letspi on {html.escape(env['env_id'])}</title>"
            "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}td,th{border:1px solid "
            "#ccc;padding:3px 6px;font-size:13px}td{text-align:right}</style></head><body>"
            f"<h1>letspi on {html.escape(env['env_id'])}</h1>"
            f"<p>{html.escape(json.dumps(env, sort_keys=True))}; "
            f"{html.escape(json.dumps(record['run']['identity']['versions'], sort_keys=True))}</p>"
            f"<h2>Per planner (95 % intervals)</h2>{_table(record)}{_paired(record)}"
            f"<h2>One episode per planner</h2>{''.join(sections)}</body></html>")
    return atomic_write_text(target, page)
