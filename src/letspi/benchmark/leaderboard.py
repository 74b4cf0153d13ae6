"""The leaderboard of a suite run, as JSON, Markdown and HTML: every planner per mode on the windows all have, with
95 % intervals (rates: Wilson grouped by ego vehicle; means: vehicle bootstrap) and paired deltas against the
reference (rates: discordant counts, exact McNemar p, ``discordant_design_effect``). ``leaderboard.json`` holds
nothing that varies between identical runs (floats to 6 significant digits)."""

from __future__ import annotations

import html
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np
import pandas as pd

from letspi.benchmark.suites import Suite
from letspi.evaluation.results import load_planner_results
from letspi.metrics.stats import (
    bootstrap_mean_interval,
    design_effect,
    paired_mean,
    paired_rate,
    rounded,
    vehicle_wilson_interval,
)

#: (leaderboard key, per-scenario flag column, label)
RATES: Final = (("cr_pct", "collision", "CR %"), ("cr_at_fault_pct", "collision_at_fault", "CR at fault %"),
                ("sr_pct", "success", "SR %"), ("lt_pct", "low_ttc", "LT %"),
                ("off_road_pct", "off_road", "off road %"))
#: (leaderboard key, per-scenario value column, label)
MEANS: Final = (("ade_m", "ade_m", "ADE m"), ("fde_m", "fde_m", "FDE m"))
#: the columns of the Markdown/HTML tables (the JSON has every key above)
SHOWN: Final = ("cr_pct", "cr_at_fault_pct", "sr_pct", "ade_m")
FORMAT: Final = 1


def _num(x: float) -> float | None:
    return None if not math.isfinite(x) else rounded(float(x))


def _aligned(eval_dir: Path, planners: Sequence[str]) -> tuple[dict[str, pd.DataFrame], list[str]]:
    """Each planner's rows on the scenario digests all of them have, in one order."""
    frames = {p: load_planner_results(eval_dir, p) for p in planners}
    missing = [p for p, f in frames.items() if f.empty]
    if missing:
        raise ValueError(f"{eval_dir}: no results of {', '.join(missing)}")
    shared = set.intersection(*(set(f["scenario_digest"]) for f in frames.values()))
    first = frames[planners[0]]
    order = [d for d in first.sort_values("row")["scenario_digest"] if d in shared]
    return {p: f.set_index("scenario_digest").loc[order] for p, f in frames.items()}, order


def mode_board(eval_dir: Path, planners: Sequence[str], groups_of: Mapping[str, str],
               reference: str | None) -> dict[str, Any]:
    """The leaderboard of one mode's results directory (module docstring)."""
    frames, order = _aligned(eval_dir, planners)
    groups = np.array([groups_of[d] for d in order], dtype=object)
    rows: dict[str, Any] = {}
    for name, frame in frames.items():
        row: dict[str, Any] = {"n": len(frame)}
        for key, col, _ in RATES:
            flags = frame[col].to_numpy(dtype=bool)
            low, high = vehicle_wilson_interval(flags, groups)
            row[key] = _num(100.0 * flags.mean()) if len(flags) else None
            row[f"{key}_ci95"] = [_num(100.0 * low), _num(100.0 * high)]
        for key, col, _ in MEANS:
            values = frame[col].to_numpy(dtype=np.float64)
            finite = np.isfinite(values)
            low, high = bootstrap_mean_interval(values, groups)
            row[key] = _num(float(values[finite].mean())) if finite.any() else None
            row[f"{key}_ci95"] = [_num(low), _num(high)]
        rows[name] = row
    paired: dict[str, Any] = {}
    if reference is not None and reference in frames:
        ref = frames[reference]
        for name, frame in frames.items():
            if name == reference:
                continue
            entry: dict[str, Any] = {}
            for key, col, _ in RATES:
                a, b = frame[col].to_numpy(dtype=bool), ref[col].to_numpy(dtype=bool)
                # how much the vehicle clustering of the discordant windows inflates the variance of a
                # count of them (1 = independent windows); ``letspi benchmark power`` sizes with it
                entry[key] = {**paired_rate(a, b, groups).record(),
                              "discordant_design_effect": _num(design_effect(a != b, groups))}
            for key, col, _ in MEANS:
                entry[key] = paired_mean(frame[col].to_numpy(dtype=np.float64), ref[col].to_numpy(dtype=np.float64),
                                         groups).record()
            paired[name] = entry
    return {"n_windows": len(order), "planners": rows, "paired": {"reference": reference, "planners": paired}}


def leaderboard(suite: Suite, boards: Mapping[str, dict[str, Any]], dataset_digest: str,
                file_digests: Mapping[int, str] | None = None, limit: int | None = None) -> dict[str, Any]:
    """The whole leaderboard: the suite, the data it ran on, and one board per mode (slug -> board);
    ``limit``: a quick try on the first N windows of each mode (recorded: not the suite's result)."""
    out: dict[str, Any] = {"format": FORMAT, "suite": suite.suite_id, "definition": suite.definition(),
                           "scripted": suite.scripted, "dataset_digest": dataset_digest, "modes": dict(boards)}
    if limit is not None:
        out["limit"] = limit
    if file_digests:
        out["highd_files_seen"] = {f"{k:02d}": v for k, v in sorted(file_digests.items())}
    return out


def to_json(board: Mapping[str, Any]) -> str:
    return json.dumps(board, indent=2, sort_keys=True) + "\n"


def _fmt(value: float | None, digits: int = 2) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def _cell(row: Mapping[str, Any], key: str) -> str:
    low, high = row[f"{key}_ci95"]
    return f"{_fmt(row[key])} ({_fmt(low)}–{_fmt(high)})"


def _delta(entry: Mapping[str, Any] | None) -> str:
    if entry is None:
        return "reference"
    low, high = entry["diff_ci95"]
    text = f"{entry['diff']:+.2f} ({_fmt(low)}–{_fmt(high)})" if entry["diff"] is not None else "–"
    if "n_only_planner" in entry:
        text += (f"; {entry['n_only_planner']} / {entry['n_only_reference']} / {entry['n_both']}, "
                 f"p {entry['p_mcnemar']:.2g}")
    return text


def _labels() -> dict[str, str]:
    return {key: label for key, _, label in (*RATES, *MEANS)}


def table_rows(board: Mapping[str, Any]) -> tuple[list[str], list[list[str]]]:
    """(header, rows) of one mode's table: the shown metrics with intervals, then the paired CR and
    CR-at-fault deltas against the reference (only planner / only reference / both, McNemar p)."""
    labels = _labels()
    reference = board["paired"]["reference"]
    header = ["planner", "n", *[f"{labels[k]} (95 % CI)" for k in SHOWN],
              f"Δ CR vs {reference}: pts (CI); only / only {reference} / both, p",
              f"Δ CR at fault vs {reference}"]
    rows = []
    for name, row in board["planners"].items():
        paired = board["paired"]["planners"].get(name)
        rows.append([name, str(row["n"]), *[_cell(row, k) for k in SHOWN],
                     _delta(paired["cr_pct"] if paired else None),
                     _delta(paired["cr_at_fault_pct"] if paired else None)])
    return header, rows


def limited_note(board: Mapping[str, Any]) -> str | None:
    """The warning a quick try's leaderboard carries (None for a full run)."""
    limit = board.get("limit")
    return None if limit is None else (f"A quick try (--limit {limit}): the first {limit} windows of each mode, "
                                       "not the suite's result; run without --limit for the leaderboard.")


def to_markdown(board: Mapping[str, Any]) -> str:
    note = limited_note(board)
    lines = [f"# Leaderboard: {board['suite']}", "", *([f"**{note}**", ""] if note else []),
             board["definition"]["name"] + ": " + board["scripted"] + ".",
             f"Dataset digest `{board['dataset_digest']}`.", ""]
    for slug, mode in board["modes"].items():
        header, rows = table_rows(mode)
        lines += [f"## {slug} ({mode['n_windows']} windows)", "", "| " + " | ".join(header) + " |",
                  "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(r) + " |" for r in rows]
        lines.append("")
    lines.append("Rates: Wilson 95 % intervals (effective n of windows grouped by vehicle); means and paired "
                 "differences: vehicle bootstrap (2,000 resamples); "
                 "p: exact McNemar on the windows only one of the two fails.")
    return "\n".join(lines) + "\n"


def to_html(board: Mapping[str, Any], reports: Mapping[str, str]) -> str:
    """A self-contained page with one table per mode and links to each mode's ``report.html``."""
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(board['suite'])}</title>",
             "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
             "td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}td:first-child{text-align:left}</style>",
             f"</head><body><h1>Leaderboard: {html.escape(board['suite'])}</h1>",
             f"<p>{html.escape(board['scripted'])}. Dataset digest <code>{board['dataset_digest']}</code>.</p>"]
    note = limited_note(board)
    if note:
        parts.append(f"<p><strong>{html.escape(note)}</strong></p>")
    for slug, mode in board["modes"].items():
        header, rows = table_rows(mode)
        link = f" (<a href='{html.escape(reports[slug])}'>report</a>)" if slug in reports else ""
        parts.append(f"<h2>{html.escape(slug)}: {mode['n_windows']} windows{link}</h2><table><tr>"
                     + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>")
        parts += ["<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows]
        parts.append("</table>")
    parts.append("<p>Rates: Wilson 95 % intervals; means and paired differences: vehicle bootstrap; p: exact "
                 "McNemar.</p></body></html>")
    return "\n".join(parts) + "\n"
