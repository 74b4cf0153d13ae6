"""Two results directories side by side, paired on the windows both hold (``letspi compare``; docs/evaluation.md):
``compare.md``, ``compare.json`` and ``compare.html`` (windows whose collision outcome differs drawn as panels, A's
planner above, B's below)."""

from __future__ import annotations

import html
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from letspi.evaluation.results import load_planner_results, planner_dir_name, stored_vehicles
from letspi.evaluation.summary import live_inference_s, paired_record, planner_statistics, timing_summary
from letspi.fsutil import atomic_write_text
from letspi.keyed import diff
from letspi.metrics.aggregate import aggregate_metrics, format_with_interval, paired_rows
from letspi.metrics.uncertainty import GROUP_COLUMN, align, intervals
from letspi.scenario.identity import scenario_digests
from letspi.scenario.store import count_scenarios, load_scenarios
from letspi.viz.outcomes import panel, stored_outcome
from letspi.viz.report import figure_to_data_uri, read_metrics

#: (label with its direction, metrics.json key) of the comparison table: ↑ higher is better, ↓ lower
COMPARED: tuple[tuple[str, str], ...] = (
    ("↓ CR %", "cr_pct"), ("↓ CR at fault %", "cr_at_fault_pct"), ("↓ SUMO CR %", "sumo_cr_pct"), ("↑ TTC s", "ttc_s"),
    ("↓ LT %", "lt_pct"), ("↑ min gap m", "min_box_gap_m"), ("↓ ADE m", "ade_m"), ("↑ SR %", "sr_pct"),
    ("↓ inference s", "inference_s"),
)
#: a rate's difference is significant below this McNemar p; a mean's when its 95 % interval excludes 0
SIGNIFICANCE_P = 0.05


class ComparisonError(ValueError):
    """Two directories that cannot be compared (the message says why, in one line)."""


# -------------------------------------------------------------------------------- two results directories


def _run(directory: Path) -> dict[str, Any]:
    path = directory / "run.json"
    if not path.exists():
        raise FileNotFoundError(f"{path}: no run.json; is {directory} an evaluation directory?")
    data: dict[str, Any] = json.loads(path.read_text())
    return data


def scenarios_file_of(directory: Path) -> Path | None:
    """The scenarios file named in ``run.json`` (as given, or beside the directory), None if absent."""
    name = _run(directory).get("dataset", {}).get("file") or ""
    for candidate in (Path(name), directory / name, directory.parent / Path(name).name) if name else ():
        if candidate.is_file():
            return candidate
    return None


@dataclass
class Comparison:
    """Planners of B paired with planners of A on their shared windows, keyed by B's label: ``reference_of``,
    aggregates and intervals, ``paired`` records (A = reference), digests whose collision outcome differs."""

    a: Path
    b: Path
    mode_a: str
    mode_b: str
    planners: list[str]
    reference: str | None = None
    reference_of: dict[str, str] = field(default_factory=dict)
    metrics_a: dict[str, dict[str, Any]] = field(default_factory=dict)
    metrics_b: dict[str, dict[str, Any]] = field(default_factory=dict)
    intervals_a: dict[str, dict[str, Any]] = field(default_factory=dict)
    intervals_b: dict[str, dict[str, Any]] = field(default_factory=dict)
    paired: dict[str, dict[str, dict[str, Any]]] = field(default_factory=dict)
    only_a: dict[str, list[str]] = field(default_factory=dict)
    only_b: dict[str, list[str]] = field(default_factory=dict)
    n_common: dict[str, int] = field(default_factory=dict)
    vehicles_from_ids: int = 0
    #: per pair: rows stored in A (its reference_of planner) and in B
    n_a: dict[str, int] = field(default_factory=dict)
    n_b: dict[str, int] = field(default_factory=dict)
    #: per pair: the configuration fields that differ (``field: A -> B``); empty for one configuration
    config_diff: dict[str, list[str]] = field(default_factory=dict)
    #: pairs of one planner label, one configuration and one mode (ordered last)
    self_pairs: list[str] = field(default_factory=list)
    #: planners of A and of B in no pair, with their stored windows
    left_out_a: dict[str, int] = field(default_factory=dict)
    left_out_b: dict[str, int] = field(default_factory=dict)

    def pair_name(self, name: str) -> str:
        """``cv-gap vs sf``; ``sf`` for a pair of one label."""
        ref = self.reference_of[name]
        return name if ref == name else f"{name} vs {ref}"

    def agrees_everywhere(self, name: str) -> bool:
        """A self-comparison whose every difference is 0 with no discordant window: nothing to show."""
        if name not in self.self_pairs:
            return False
        for rec in self.paired[name].values():
            if rec.get("diff") not in (0, 0.0, None) or rec.get("n_only_planner") or rec.get("n_only_reference"):
                return False
        return True

    def shown(self) -> list[str]:
        """The pairs the table shows, self-comparisons last (those that agree everywhere left out)."""
        return [n for n in self.planners if not self.agrees_everywhere(n)]

    def table_rows(self) -> list[dict[str, Any]]:
        """Per pair: n, collision counts and per compared key A, B (values and intervals) and the paired record."""
        rows = []
        for name in self.planners:
            row: dict[str, Any] = {"planner": name, "reference": self.reference_of[name], "n": self.n_common[name],
                                   "n_a": self.n_a.get(name), "n_b": self.n_b.get(name),
                                   "config_diff": self.config_diff.get(name, []),
                                   "self_comparison": name in self.self_pairs,
                                   "collides_only_a": len(self.only_a[name]), "collides_only_b": len(self.only_b[name])}
            for _, key in COMPARED:
                va, vb = self.metrics_a[name].get(key), self.metrics_b[name].get(key)
                rec = self.paired[name].get(key, {})
                row[key] = {"a": va, "b": vb, "a_ci95": self.intervals_a[name].get(key),
                            "b_ci95": self.intervals_b[name].get(key), "delta": rec.get("diff"),
                            "delta_ci95": rec.get("diff_ci95"), "p_mcnemar": rec.get("p_mcnemar"),
                            "verdict": verdict(key, rec)}
            rows.append(row)
        return rows

    def paired_entry(self) -> dict[str, Any]:
        """metrics.json's "paired" structure: A's planner is the reference, B's the planner."""
        return {"reference": self.reference or "A", "reference_dir": str(self.a), "planner_dir": str(self.b),
                "planners": self.paired}

    def header(self) -> str:
        pairing = (f"every planner of B against {self.reference} of A" if self.reference
                   else "each planner of B against the planner of A with its label")
        lines = [f"A = {self.a} ({self.mode_a}), B = {self.b} ({self.mode_b}): {pairing}, on the windows both hold. "
                 "Values with 95 % intervals (rates: Wilson, windows grouped by ego vehicle; means: bootstrap over ego "
                 "vehicles); Δ = B − A, paired, with its vehicle-bootstrap interval; rates: windows only A / only B / "
                 "both have the event (for SR: succeed) and the exact McNemar p. ↑ higher is better, ↓ lower; "
                 f"**bold**: significant (interval excludes 0; rates: p < {SIGNIFICANCE_P:g}), with which side is "
                 "better."]
        if self.vehicles_from_ids:
            lines.append(f"Note: {self.vehicles_from_ids} rows were stored without their ego vehicle (an older "
                         "letspi): grouped by the recording and ego id of their scenario id.")
        return "\n".join(lines)

    def notes(self) -> list[str]:
        """What each pair compares (windows, configuration differences) and what was left out."""
        out = []
        for name in self.planners:
            ref = self.reference_of[name]
            windows = f"{self.n_common[name]} shared windows"
            dropped = [f"{n} only in A" for n in [self.n_a.get(name, 0) - self.n_common[name]] if n > 0]
            dropped += [f"{n} only in B" for n in [self.n_b.get(name, 0) - self.n_common[name]] if n > 0]
            if dropped:
                windows += f" (left out: {', '.join(dropped)})"
            if name in self.self_pairs:
                what = "the same configuration in A and B" + (
                    ": identical on every shared window, left out of the table" if self.agrees_everywhere(name)
                    else "")
            elif self.config_diff.get(name):
                what = "configuration A -> B: " + "; ".join(self.config_diff[name])
            elif ref == name:
                what = f"the same configuration, {self.mode_a} -> {self.mode_b}"
            else:
                what = "another planner kind"
            out.append(f"{name} (B) vs {ref} (A): {windows}; {what}")
        for side, left in (("A", self.left_out_a), ("B", self.left_out_b)):
            if left:
                listed = ", ".join(f"{n} ({w} windows)" for n, w in left.items())
                out.append(f"planners of {side} in no pair: {listed}")
        return out

    def keys(self) -> tuple[tuple[str, str], ...]:
        """The compared metrics that some pair has a value of."""
        return tuple((label, key) for label, key in COMPARED
                     if any(isinstance(self.metrics_a[p].get(key), int | float)
                            or isinstance(self.metrics_b[p].get(key), int | float) for p in self.planners))

    def cells(self) -> list[list[str]]:
        """The table: per shown pair and compared metric (pair, metric, n, A, B, Δ B − A with interval,
        only A, only B, both, McNemar p, verdict); "–" where a metric has no counts or no value."""
        keys = self.keys()
        out = []
        for name in self.shown():
            rows = {r[1]: r for r in paired_rows({"planners": {name: self.paired[name]}}, keys)}
            for label, key in keys:
                a = format_with_interval(self.metrics_a[name].get(key), self.intervals_a[name].get(key))
                b = format_with_interval(self.metrics_b[name].get(key), self.intervals_b[name].get(key))
                r = rows.get(label)  # planner, metric, n, Δ, only planner (B), only reference (A), both, p
                tail = ["–"] * 5 if r is None else [r[3], r[5], r[4], r[6], r[7]]
                out.append([self.pair_name(name), label, str(self.n_common[name]) if r is None else r[2], a, b, *tail,
                            verdict(key, self.paired[name].get(key, {}))])
        return out

    def markdown(self) -> str:
        lines = [self.header(), "", *(f"- {note}" for note in self.notes()), "",
                 "| " + " | ".join(HEAD) + " |", "|---|---|" + "---:|" * (len(HEAD) - 3) + "---|"]
        for row in self.cells():
            if row[-1]:
                row = [*row[:5], f"**{row[5]}**", *row[6:]]
            lines.append("| " + " | ".join(row) + " |")
        return "\n".join(lines)


#: the comparison table's columns
HEAD = ("pair (B vs A)", "metric", "n", "A", "B", "Δ B − A (95 % CI)", "only A", "only B", "both", "p", "B is")


def direction(key: str) -> int:
    """+1 where higher is better (↑), -1 where lower is (↓), 0 unknown (``COMPARED``'s marks)."""
    label = next((label for label, k in COMPARED if k == key), "")
    return 1 if label.startswith("↑") else -1 if label.startswith("↓") else 0


def verdict(key: str, rec: dict[str, Any]) -> str:
    """"better" / "worse" for B when the difference is significant (``SIGNIFICANCE_P``), else ""."""
    d = rec.get("diff")
    if not isinstance(d, int | float) or d == 0 or direction(key) == 0:
        return ""
    p, ci = rec.get("p_mcnemar"), rec.get("diff_ci95")
    if isinstance(p, int | float):
        significant = p < SIGNIFICANCE_P
    else:
        significant = isinstance(ci, list) and None not in ci and (ci[0] > 0 or ci[1] < 0)
    if not significant:
        return ""
    return "better" if d * direction(key) > 0 else "worse"


def _config_record(directory: Path, name: str) -> dict[str, Any]:
    path = directory / "per_scenario" / planner_dir_name(name) / "config.json"
    record: dict[str, Any] = json.loads(path.read_text()) if path.exists() else {}
    return record


def _identity(directory: Path) -> dict[str, Any]:
    identity: dict[str, Any] = _run(directory).get("identity", {})
    return identity


def _shared_aggregate(frame: pd.DataFrame) -> dict[str, Any]:
    """The aggregate of a planner's rows (metrics and timing, as metrics.json has them)."""
    return {**aggregate_metrics(frame, inference_time_s=live_inference_s(frame)), **timing_summary(frame, 0.0)}


def compare_dirs(a: Path | str, b: Path | str, reference: str | None = None) -> Comparison:
    """Pair the planners of B with those of A on the windows both hold; ``reference``:
    a planner label of A that every planner of B is compared with (default: the same labels)."""
    a, b = Path(a), Path(b)
    ia, ib = _identity(a), _identity(b)
    if ia.get("metrics_config") != ib.get("metrics_config"):
        raise ComparisonError(f"{a} and {b} were scored under different metrics configurations: their figures "
                              "do not mean the same; evaluate both under one configuration")
    mode_a, mode_b = str(ia.get("mode", "open-loop")), str(ib.get("mode", "open-loop"))
    ma, mb = read_metrics(a), read_metrics(b)
    if reference is not None:
        if reference not in ma:
            raise ComparisonError(f"--reference {reference!r} is not a planner of {a} ({', '.join(ma) or 'none'})")
        if mode_a != mode_b:
            raise ComparisonError(f"{a} is {mode_a}, {b} is {mode_b}: planners compared with --reference must be "
                                  "evaluated in the same mode (without --reference, a planner is compared with itself "
                                  "across modes)")
        pairs = {name: reference for name in mb if not (a.resolve() == b.resolve() and name == reference)}
    else:
        pairs = {name: name for name in ma if name in mb}
        if not pairs:
            raise ComparisonError(f"{a} ({', '.join(ma) or 'none'}) and {b} ({', '.join(mb) or 'none'}) share no "
                                  "planner label; pass --reference LABEL to compare B's planners with a planner of A")
    records = {name: (_config_record(a, ref), _config_record(b, name)) for name, ref in pairs.items()}
    same = {name for name, (ra, rb) in records.items()
            if pairs[name] == name and mode_a == mode_b and ra.get("key") and ra.get("key") == rb.get("key")}
    order = [n for n in pairs if n not in same] + [n for n in pairs if n in same]  # self-comparisons last
    cmp = Comparison(a, b, mode_a, mode_b, order, reference, {n: pairs[n] for n in order})
    cmp.self_pairs = [n for n in order if n in same]
    cmp.config_diff = {name: diff(ra.get("identity") or {}, rb.get("identity") or {})  # one kind's settings
                       for name, (ra, rb) in records.items()
                       if ra and rb and ra.get("kind") == rb.get("kind") and ra.get("key") != rb.get("key")}
    cmp.left_out_a = {n: int(m.get("n", 0)) for n, m in ma.items() if n not in set(pairs.values())}
    cmp.left_out_b = {n: int(m.get("n", 0)) for n, m in mb.items() if n not in pairs}
    for name, ref in pairs.items():
        ra_rows, rb_rows = load_planner_results(a, ref), load_planner_results(b, name)
        cmp.n_a[name], cmp.n_b[name] = len(ra_rows), len(rb_rows)
        fa, fb = align(ra_rows, rb_rows)
        if not len(fa):
            raise ComparisonError(f"{a} ({ref}) and {b} ({name}) share no scenario: other scenarios (no common "
                                  "scenario digest); compare runs of the same scenarios")
        groups, from_ids = stored_vehicles(fb if GROUP_COLUMN in fb else fa)
        cmp.vehicles_from_ids = max(cmp.vehicles_from_ids, from_ids)
        fa, fb = fa.assign(**{GROUP_COLUMN: groups}), fb.assign(**{GROUP_COLUMN: groups})
        cmp.metrics_a[name], cmp.metrics_b[name] = _shared_aggregate(fa), _shared_aggregate(fb)
        cmp.intervals_a[name] = intervals(planner_statistics(fa), groups)
        cmp.intervals_b[name] = intervals(planner_statistics(fb), groups)
        cmp.paired[name] = paired_record(fb, fa)
        ca, cb = fa["collision"].to_numpy(dtype=bool), fb["collision"].to_numpy(dtype=bool)
        digests = fa["scenario_digest"].astype(str)
        cmp.only_a[name] = digests[ca & ~cb].tolist()
        cmp.only_b[name] = digests[cb & ~ca].tolist()
        cmp.n_common[name] = len(fa)
    return cmp


def _rows_by_digest(directory: Path, name: str, digests: list[str]) -> dict[str, dict[Any, Any]]:
    frame = load_planner_results(directory, name, with_plans=True)
    frame = frame[frame["scenario_digest"].isin(set(digests))]
    return {str(r["scenario_digest"]): r for r in frame.to_dict("records")}


def comparison_panels(cmp: Comparison, n_examples: int) -> dict[str, list[tuple[str, str]]]:
    """Per planner, up to ``n_examples`` panels (caption, PNG data URI) of scenarios whose outcome
    differs (collides in B only first); empty when the scenarios file is not found."""
    scen = scenarios_file_of(cmp.b) or scenarios_file_of(cmp.a)
    out: dict[str, list[tuple[str, str]]] = {}
    if scen is None or n_examples <= 0:
        return out
    n_file = count_scenarios(scen)
    for name in cmp.planners:
        ref = cmp.reference_of[name]
        picked = [(d, f"collides with {name} (B) only") for d in cmp.only_b[name][:n_examples]]
        picked += [(d, f"collides with {ref} (A) only") for d in cmp.only_a[name][: n_examples - len(picked)]]
        if not picked:
            continue
        ra = _rows_by_digest(cmp.a, cmp.reference_of[name], [d for d, _ in picked])
        rb = _rows_by_digest(cmp.b, name, [d for d, _ in picked])
        for digest, why in picked:
            rec_a, rec_b = ra.get(digest), rb.get(digest)
            if rec_a is None or rec_b is None or int(rec_b["row"]) >= n_file:
                continue
            sub = load_scenarios(scen, [int(rec_b["row"])])
            if str(scenario_digests(sub)[0]) != digest:
                continue
            top = stored_outcome(f"A: {ref} ({cmp.mode_a})", sub, rec_a)
            bottom = stored_outcome(f"B: {name} ({cmp.mode_b})", sub, rec_b)
            caption = f"scenario {rec_b['scenario_id']}: {why}"
            fig = panel(sub, top, bottom, title=f"{cmp.pair_name(name)}: {caption}")
            out.setdefault(name, []).append((caption, figure_to_data_uri(fig, dpi=85)))
    return out


def write_comparison(a: Path | str, b: Path | str, out_dir: Path | str, *, n_examples: int = 3,
                     reference: str | None = None) -> Comparison:
    """``compare.md``, ``compare.json`` and ``compare.html`` in ``out_dir``; returns the comparison."""
    cmp = compare_dirs(a, b, reference)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    text = cmp.markdown()
    atomic_write_text(out / "compare.md", text + "\n")
    payload = {"a": {"dir": str(cmp.a), "mode": cmp.mode_a}, "b": {"dir": str(cmp.b), "mode": cmp.mode_b},
               "planners": cmp.table_rows(), "paired": cmp.paired_entry(),
               "left_out": {"a": cmp.left_out_a, "b": cmp.left_out_b}, "notes": cmp.notes(),
               "collides_only_a": cmp.only_a, "collides_only_b": cmp.only_b}
    atomic_write_text(out / "compare.json", json.dumps(payload, indent=2, allow_nan=False, default=float) + "\n")
    atomic_write_text(out / "compare.html", comparison_html(cmp, comparison_panels(cmp, n_examples)) + "\n")
    return cmp


def comparison_html(cmp: Comparison, panels: dict[str, list[tuple[str, str]]]) -> str:
    """compare.html: the header, what each pair compares, the table (significant differences coloured by
    whether B is better or worse) and the panels of the scenarios whose outcome differs."""
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>letspi compare</title>"
             "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
             "td,th{border:1px solid #ccc;padding:3px 6px;text-align:right}"
             "td:first-child,td:nth-child(2){text-align:left}tr.better td{background:#e3f4e1}"
             "tr.worse td{background:#fbe3e1}tr.better td.d,tr.worse td.d{font-weight:bold}"
             "tr.first td{border-top:2px solid #888}img{max-width:100%}</style></head><body>",
             f"<h1>letspi compare</h1><p>A: <code>{html.escape(str(cmp.a))}</code> ({html.escape(cmp.mode_a)}); "
             f"B: <code>{html.escape(str(cmp.b))}</code> ({html.escape(cmp.mode_b)})</p>",
             "<p>" + html.escape(cmp.header()).replace("\n", "<br>").replace("**bold**", "coloured") + "</p>",
             "<ul>" + "".join(f"<li>{html.escape(note)}</li>" for note in cmp.notes()) + "</ul>",
             "<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in HEAD) + "</tr>"]
    previous = None
    for row in cmp.cells():
        classes = " ".join(c for c in (row[-1], "first" if row[0] != previous else "") if c)
        previous = row[0]
        cells = "".join(f"<td{' class=d' if i == 5 else ''}>{html.escape(c)}</td>" for i, c in enumerate(row))
        parts.append(f"<tr class='{classes}'>{cells}</tr>")
    parts.append("</table>")
    if not panels:
        parts.append("<p>No scenario changes its collision outcome (or the scenarios file was not found).</p>")
    for name, items in panels.items():
        parts.append(f"<h2>{html.escape(cmp.pair_name(name))}: scenarios whose outcome differs</h2>")
        for caption, uri in items:
            parts.append(f"<figure><img src='{uri}' alt='{html.escape(caption)}'><figcaption>"
                         f"{html.escape(caption)}</figcaption></figure>")
    parts.append("</body></html>")
    return "\n".join(parts)
