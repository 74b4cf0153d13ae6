"""``write_report``: a self-contained HTML report of an evaluation directory (images inline as base64 PNG).

Sections, each skipped without its input: metrics, distributions, the worst scenarios (stored plans, never
re-planned), decisions, and ablations from ``DIR/ablations/``: ``memory_size.json`` ``{"total": N (optional),
"points": [{"memory_size", "metrics"}, ..]}`` and ``llm_combinations.json`` ``{"combinations": [{"name", "fast",
"physics", "metrics"}, ..]}`` (``metrics.json`` keys); an unreadable file yields a warning in its section."""

from __future__ import annotations

import base64
import io
import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jinja2
import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from letspi.constants import N_FUTURE
from letspi.evaluation.closed_loop import CL_PLAN_XY
from letspi.evaluation.results import load_planner_results
from letspi.fsutil import atomic_write_text
from letspi.metrics.aggregate import TABLE_COLUMNS, format_with_interval, paired_caption, paired_rows
from letspi.metrics.config import MetricsConfig
from letspi.planners.base import PlanBatch
from letspi.scenario.identity import scenario_digests
from letspi.scenario.store import count_scenarios, load_scenarios
from letspi.viz import style
from letspi.viz.decisions import decision_sections
from letspi.viz.figure import plot_scenario
from letspi.viz.outcomes import closed_loop_report_figure

#: extra columns of the report's metrics table (after the paper columns)
EXTRA_COLUMNS: tuple[tuple[str, str], ...] = (("↑ min gap (m)", "min_box_gap_m"), ("n", "n"))
#: labels of the paper metrics for ablation plots
METRIC_TITLES: dict[str, str] = {key: label for label, key in TABLE_COLUMNS}


@dataclass
class WorstScenario:
    """One entry of the worst-scenarios section."""

    anchor: str
    scenario_id: str
    caption: str
    image: str | None = None
    note: str | None = None


@dataclass
class PlannerSection:
    """The worst scenarios of one planner."""

    name: str
    anchor: str
    scenarios: list[WorstScenario] = field(default_factory=list)
    note: str | None = None


def slug(text: str) -> str:
    """An HTML id fragment from ``text`` (lower case, [a-z0-9-] only)."""
    s = re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")
    return s or "x"


def figure_to_data_uri(fig: Figure, dpi: int = 110) -> str:
    """PNG of ``fig`` as a ``data:`` URI."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _fmt(value: object, digits: int = 2) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, float):
        return "n/a" if math.isnan(value) else f"{value:.{digits}f}"
    return str(value)


# ------------------------------------------------------------------------------------------- inputs
def read_metrics(eval_dir: Path) -> dict[str, dict[str, Any]]:
    """``{planner: aggregated metrics}`` of ``eval_dir/metrics.json`` (FileNotFoundError if absent)."""
    path = eval_dir / "metrics.json"
    if not path.exists():
        raise FileNotFoundError(f"{path}: no metrics.json; is {eval_dir} an evaluation directory?")
    data = json.loads(path.read_text())
    planners = data.get("planners")
    if not isinstance(planners, dict):
        raise ValueError(f"{path}: expected {{'planners': {{name: metrics}}}}")
    return planners


def _run_mode(eval_dir: Path) -> str:
    run = eval_dir / "run.json"
    if not run.exists():
        return "open-loop"
    return str(json.loads(run.read_text()).get("identity", {}).get("mode", "open-loop"))


def _scenarios_file(eval_dir: Path) -> Path | None:
    run = eval_dir / "run.json"
    if not run.exists():
        return None
    name = json.loads(run.read_text()).get("dataset", {}).get("file") or ""
    if not name:
        return None
    for candidate in (Path(name), eval_dir / name, eval_dir.parent / Path(name).name):
        if candidate.exists():
            return candidate
    return None


# ------------------------------------------------------------------------------------ distributions
def distributions_figure(frames: Mapping[str, pd.DataFrame], ttc_cap_s: float) -> Figure | None:
    """Box plots per planner of min TTC (capped), min box gap and min PET (finite); None if no data."""
    names = [n for n, f in frames.items() if len(f)]
    if not names:
        return None
    panels = (
        ("min_ttc_s", f"minimum TTC [s] (capped at {ttc_cap_s:g} s)"),
        ("min_box_gap_m", "minimum box gap [m]"),
        ("min_pet_s", "minimum PET [s] (finite only)"),
    )
    with style.letspi_style():
        fig = Figure(figsize=(13.0, 1.3 + 0.6 * len(names)), layout="constrained")
        axes = fig.subplots(1, len(panels), sharey=True)
        for ax, (col, label) in zip(axes, panels, strict=True):
            data, counts = [], []
            for name in names:
                df = frames[name]
                v = np.asarray(df[col], dtype=np.float64) if col in df else np.array([])
                n_finite = int(np.isfinite(v).sum())
                if col == "min_ttc_s":
                    v = np.minimum(v[~np.isnan(v)], ttc_cap_s)
                else:
                    v = v[np.isfinite(v)]
                data.append(v if v.size else np.array([np.nan]))
                counts.append(f"finite: {n_finite} of {len(df)}")
            pos = np.arange(len(names))[::-1]
            bp = ax.boxplot(data, positions=pos, orientation="horizontal", widths=0.55, showmeans=True,
                            patch_artist=True, flierprops={"markersize": 3, "alpha": 0.5},
                            meanprops={"marker": "^", "markerfacecolor": "white", "markeredgecolor": "black"},
                            medianprops={"color": "black"})
            for k, box in enumerate(bp["boxes"]):
                box.set_facecolor(style.plan_colour(k))
                box.set_alpha(0.75)
            ax.set_yticks(pos, names)
            for p, text in zip(pos, counts, strict=True):
                ax.text(0.01, p + 0.31, text, transform=ax.get_yaxis_transform(), fontsize=7.5, color="#444444",
                        va="bottom", ha="left")
            ax.set_ylim(-0.6, len(names) - 0.25)
            ax.set_xlabel(label)
            ax.grid(axis="y", visible=False)
        axes[0].set_ylabel("planner")
        fig.suptitle("Per-scenario safety metrics (box: quartiles, line: median, ▲: mean)",
                     fontsize=style.BASE_FONT_SIZE + 1)
    return fig


# ---------------------------------------------------------------------------------- worst scenarios
def worst_rows(frame: pd.DataFrame, n: int) -> pd.DataFrame:
    """The ``n`` worst scenarios: collisions first, then lowest min TTC, then smallest min gap."""
    if not len(frame):
        return frame
    def col(name: str) -> np.ndarray:
        if name not in frame:
            return np.full(len(frame), np.inf)
        v = np.asarray(frame[name], dtype=np.float64)
        return np.where(np.isnan(v), np.inf, v)

    collided = np.asarray(frame["collision"], dtype=np.float64) if "collision" in frame else np.zeros(len(frame))
    key = pd.DataFrame({"c": -collided, "t": col("min_ttc_s"), "g": col("min_box_gap_m")}, index=frame.index)
    order = key.sort_values(["c", "t", "g"], kind="stable").index
    return frame.loc[order[:n]]


def _caption(row: pd.Series) -> str:
    parts = [f"min TTC {_fmt(float(row.get('min_ttc_s', math.nan)), 2)} s",
             f"min gap {_fmt(float(row.get('min_box_gap_m', math.nan)), 2)} m",
             f"min PET {_fmt(float(row.get('min_pet_s', math.nan)), 2)} s"]
    if bool(row.get("collision", False)):
        parts.insert(0, "COLLISION")
    return " · ".join(p.replace("inf", "∞") for p in parts)


def worst_sections(eval_dir: Path, frames: Mapping[str, pd.DataFrame],
                   n_worst: int) -> tuple[list[PlannerSection], str | None]:
    """Worst scenarios of every planner, drawn from the stored plans; also a section-level note."""
    scen_file = _scenarios_file(eval_dir)
    if scen_file is None:
        note = "The scenarios file named in run.json was not found: worst scenarios are listed without diagrams."
        return [_listed(name, frame, n_worst) for name, frame in frames.items()], note
    n_file = count_scenarios(scen_file)
    sections: list[PlannerSection] = []
    for name, frame in frames.items():
        sec = PlannerSection(name=name, anchor=f"worst-{slug(name)}")
        rows = worst_rows(frame, n_worst)
        stored = load_planner_results(eval_dir, name, with_plans=True).set_index("scenario_digest")
        for _, row in rows.iterrows():
            sid = str(row["scenario_id"])
            item = WorstScenario(anchor=f"{sec.anchor}-{slug(sid)}", scenario_id=sid, caption=_caption(row))
            pos = int(row["row"])
            sub = load_scenarios(scen_file, [pos]) if pos < n_file else None
            if sub is None or str(scenario_digests(sub)[0]) != str(row["scenario_digest"]):
                item.note = f"scenario not found unchanged in {scen_file}: listed without a diagram"
            else:
                rec = stored.loc[str(row["scenario_digest"])]
                if CL_PLAN_XY in stored.columns:  # closed loop: its t = 0 plan in open loop above the run
                    record = {**{str(k): v for k, v in rec.items()}, "scenario_id": sid}
                    fig = closed_loop_report_figure(sub, record, name, _run_mode(eval_dir))
                else:
                    plan = PlanBatch(xy_m=np.asarray(rec["plan_xy_m"], np.float64).reshape(1, N_FUTURE, 2),
                                     vxy_mps=np.asarray(rec["plan_vxy_mps"], np.float64).reshape(1, N_FUTURE, 2),
                                     goals_xy_m=np.asarray(rec["plan_goal_xy_m"], np.float64).reshape(1, 2))
                    fig = plot_scenario(sub, 0, {name: plan}, title=f"{name}: scenario {sid}", width_in=13.0)
                item.image = figure_to_data_uri(fig, dpi=90)
            sec.scenarios.append(item)
        sections.append(sec)
    return sections, None


def _listed(name: str, frame: pd.DataFrame, n_worst: int) -> PlannerSection:
    sec = PlannerSection(name=name, anchor=f"worst-{slug(name)}")
    for _, row in worst_rows(frame, n_worst).iterrows():
        sid = str(row["scenario_id"])
        sec.scenarios.append(WorstScenario(f"{sec.anchor}-{slug(sid)}", sid, _caption(row)))
    return sec


# ---------------------------------------------------------------------------------------- ablations
def _metric_keys(entries: Sequence[Mapping[str, Any]]) -> list[str]:
    keys = [key for _, key in TABLE_COLUMNS if key != "inference_s"]
    return [k for k in keys if any(isinstance(e.get("metrics", {}).get(k), int | float) for e in entries)]


def memory_size_figure(data: Mapping[str, Any]) -> Figure:
    """Paper metrics against the memory size (one small panel per metric)."""
    points = sorted(data["points"], key=lambda p: float(p["memory_size"]))
    if not points:
        raise ValueError("no points")
    keys = _metric_keys(points)
    if not keys:
        raise ValueError("no known metric keys in 'metrics'")
    total = data.get("total")
    x = np.array([float(p["memory_size"]) for p in points])
    xlabel = "memory size [entries]"
    if isinstance(total, int | float) and total > 0:
        x = 100.0 * x / float(total)
        xlabel = f"memory size [% of {total:g}]"
    ncol = min(3, len(keys))
    nrow = math.ceil(len(keys) / ncol)
    with style.letspi_style():
        fig = Figure(figsize=(4.2 * ncol, 2.8 * nrow), layout="constrained")
        axes = np.atleast_1d(fig.subplots(nrow, ncol, squeeze=False)).ravel()
        for ax, key in zip(axes, keys, strict=False):
            y = np.array([float(p["metrics"].get(key, math.nan) or math.nan) for p in points])
            ax.plot(x, y, marker="o", color=style.plan_colour(0), lw=2)
            ax.set_title(METRIC_TITLES.get(key, key), loc="left")
            ax.set_xlabel(xlabel)
        for ax in axes[len(keys):]:
            ax.set_visible(False)
    return fig


def llm_combinations_figure(data: Mapping[str, Any]) -> Figure:
    """Paper metrics per LLM combination (horizontal bars, one panel per metric)."""
    combos = list(data["combinations"])
    if not combos:
        raise ValueError("no combinations")
    keys = _metric_keys(combos)
    if not keys:
        raise ValueError("no known metric keys in 'metrics'")
    names = [str(c.get("name") or f"{c.get('fast', '?')} + {c.get('physics', '?')}") for c in combos]
    ncol = min(3, len(keys))
    nrow = math.ceil(len(keys) / ncol)
    with style.letspi_style():
        fig = Figure(figsize=(4.4 * ncol, (0.8 + 0.35 * len(names)) * nrow + 0.3), layout="constrained")
        axes = np.atleast_1d(fig.subplots(nrow, ncol, squeeze=False, sharey=True)).ravel()
        pos = np.arange(len(names))[::-1]
        for ax, key in zip(axes, keys, strict=False):
            y = np.array([float(c["metrics"].get(key, math.nan) or math.nan) for c in combos])
            ax.barh(pos, y, color=[style.plan_colour(k) for k in range(len(names))], height=0.6)
            ax.set_yticks(pos, names)
            ax.set_title(METRIC_TITLES.get(key, key), loc="left")
            ax.grid(axis="y", visible=False)
        for ax in axes[len(keys):]:
            ax.set_visible(False)
    return fig


def _ablation(path: Path, kind: str) -> dict[str, Any] | None:
    if not path.exists():
        return None
    anchor = "ablation-" + slug(path.stem)
    try:
        data = json.loads(path.read_text())
        if kind == "memory":
            fig = memory_size_figure(data)
            entries = sorted(data["points"], key=lambda p: float(p["memory_size"]))
            labels = [_fmt(p["memory_size"], 0) for p in entries]
        else:
            fig = llm_combinations_figure(data)
            entries = list(data["combinations"])
            labels = [str(c.get("name") or f"{c.get('fast', '?')} + {c.get('physics', '?')}") for c in entries]
        keys = _metric_keys(entries)
        rows = [[label, *[_fmt(e["metrics"].get(k)) for k in keys]] for label, e in zip(labels, entries, strict=True)]
        return {"anchor": anchor, "file": path.name, "image": figure_to_data_uri(fig),
                "header": [METRIC_TITLES.get(k, k) for k in keys], "rows": rows, "warning": None}
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        return {"anchor": anchor, "file": path.name, "image": None, "header": [], "rows": [],
                "warning": f"could not read {path.name}: {type(exc).__name__}: {exc}"}


# ------------------------------------------------------------------------------------------- report
def _environment() -> jinja2.Environment:
    return jinja2.Environment(
        loader=jinja2.PackageLoader("letspi.viz", "templates"),
        autoescape=jinja2.select_autoescape(["html", "j2"]),
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )


def _ablations(abl_dir: Path) -> list[dict[str, Any]]:
    """The ablation tables stored beside the evaluation (memory size, LLM combinations), titled."""
    ablations = [a for a in (_ablation(abl_dir / "memory_size.json", "memory"),
                             _ablation(abl_dir / "llm_combinations.json", "llm")) if a is not None]
    for a in ablations:
        a["title"] = "Memory size" if a["file"] == "memory_size.json" else "LLM combinations"
    return ablations


def _metrics_tables(eval_dir: Path, metrics: Mapping[str, Mapping[str, Any]], columns: Sequence[tuple[str, str]]
                    ) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The metrics table's rows (values with their intervals) and the paired table's template fields."""
    summary = json.loads((eval_dir / "metrics.json").read_text())
    intervals: dict[str, dict[str, Any]] = summary.get("intervals") or {}
    pairs: dict[str, Any] = summary.get("paired") or {}
    rows: list[dict[str, Any]] = [
        {"name": name, "cells": [format_with_interval(agg.get(key), intervals.get(name, {}).get(key))
                                 for _, key in columns]}
        for name, agg in metrics.items()]
    return rows, {"with_intervals": bool(intervals), "paired_reference": pairs.get("reference"),
                  "paired_caption": paired_caption(str(pairs.get("reference"))) if pairs else "",
                  "paired_rows": paired_rows(pairs) if pairs else []}


def write_report(
    eval_dir: Path | str,
    out_html: Path | str | None = None,
    *,
    n_worst: int = 3,
    with_diagrams: bool = True,
    config: MetricsConfig | None = None,
) -> Path:
    """Write the HTML report of ``eval_dir`` (default ``eval_dir/report.html``) and return its path. ``n_worst``:
    worst scenarios per planner; ``with_diagrams`` False lists them only; ``config`` gives the TTC cap."""
    eval_dir = Path(eval_dir)
    out = Path(out_html) if out_html is not None else eval_dir / "report.html"
    config = config or MetricsConfig()
    metrics = read_metrics(eval_dir)
    frames = {name: load_planner_results(eval_dir, name) for name in metrics}
    frames = {name: f for name, f in frames.items() if len(f)}
    columns = [*TABLE_COLUMNS, *EXTRA_COLUMNS]
    table_rows, tables = _metrics_tables(eval_dir, metrics, columns)
    dist_fig = distributions_figure(frames, config.ttc_cap_s)
    worst: list[PlannerSection] = []
    worst_note = None
    if frames:
        if with_diagrams:
            worst, worst_note = worst_sections(eval_dir, frames, n_worst)
        else:
            worst = [_listed(name, frame, n_worst) for name, frame in frames.items()]
    decisions = (decision_sections(eval_dir, frames, _scenarios_file(eval_dir), lambda f: figure_to_data_uri(f, dpi=90))
                 if frames and with_diagrams else [])
    worst_anchor = {sec.name: sec.anchor for sec in worst}
    for table_row in table_rows:
        table_row["anchor"] = worst_anchor.get(str(table_row["name"]))
    run_info: dict[str, Any] = {}
    if (eval_dir / "run.json").exists():
        run_info = json.loads((eval_dir / "run.json").read_text())
    template = _environment().get_template("report.html.j2")
    page = template.render(
        title=f"letspi evaluation report: {eval_dir.name}",
        eval_dir=str(eval_dir),
        run=run_info,
        header=[label for label, _ in columns],
        table_rows=table_rows,
        **tables,
        distributions=figure_to_data_uri(dist_fig) if dist_fig is not None else None,
        ttc_cap_s=config.ttc_cap_s,
        worst=worst,
        worst_note=worst_note,
        decisions=decisions,
        n_worst=n_worst,
        ablations=_ablations(eval_dir / "ablations"),
    )
    return atomic_write_text(out, page)
