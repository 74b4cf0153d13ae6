"""Two results directories of the same scenarios side by side: ``letspi compare``.

``compare_dirs`` / ``write_comparison``: e.g. open loop (A) and closed loop (B) of the same
scenarios and metrics configuration: a table of metric deltas per planner (``compare.md``,
``compare.json``) and an HTML page (``compare.html``) with, per planner, the scenarios whose
collision outcome differs, drawn as closed-loop panels (A above, B below; ``letspi.viz.outcomes``).
"""

from __future__ import annotations

import html
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from letspi.evaluation.harness import load_planner_results
from letspi.fsutil import atomic_write_text
from letspi.scenario.identity import scenario_digests
from letspi.scenario.store import count_scenarios, load_scenarios
from letspi.viz.outcomes import panel, stored_outcome
from letspi.viz.report import figure_to_data_uri, read_metrics

#: (label, metrics.json key) of the comparison table
COMPARED: tuple[tuple[str, str], ...] = (
    ("CR %", "cr_pct"), ("CR at fault %", "cr_at_fault_pct"), ("SUMO CR %", "sumo_cr_pct"), ("TTC s", "ttc_s"),
    ("LT %", "lt_pct"), ("min gap m", "min_box_gap_m"), ("ADE m", "ade_m"), ("SR %", "sr_pct"),
    ("inference s", "inference_s"),
)


# ------------------------------------------------------------------------------------------------
# Two results directories
# ------------------------------------------------------------------------------------------------


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
    """Two results directories of the same scenarios: per planner, both aggregates and the
    scenarios whose collision outcome differs (digests; ``only_a``: collides in A only)."""

    a: Path
    b: Path
    mode_a: str
    mode_b: str
    planners: list[str]
    metrics_a: dict[str, dict[str, Any]]
    metrics_b: dict[str, dict[str, Any]]
    only_a: dict[str, list[str]] = field(default_factory=dict)
    only_b: dict[str, list[str]] = field(default_factory=dict)
    n_common: dict[str, int] = field(default_factory=dict)

    def table_rows(self) -> list[dict[str, Any]]:
        rows = []
        for name in self.planners:
            a, b = self.metrics_a[name], self.metrics_b[name]
            row: dict[str, Any] = {"planner": name, "n": self.n_common[name],
                                   "collides_only_a": len(self.only_a[name]), "collides_only_b": len(self.only_b[name])}
            for _, key in COMPARED:
                va, vb = a.get(key), b.get(key)
                delta = float(vb) - float(va) if isinstance(va, int | float) and isinstance(vb, int | float) else None
                row[key] = {"a": va, "b": vb, "delta": delta}
            rows.append(row)
        return rows

    def markdown(self) -> str:
        keys = [(label, key) for label, key in COMPARED
                if any(isinstance(self.metrics_a[p].get(key), int | float)
                       or isinstance(self.metrics_b[p].get(key), int | float) for p in self.planners)]
        head = ["planner", "n", *[f"{label} A → B (Δ)" for label, _ in keys], "collide only A / only B"]
        lines = [f"A = {self.a} ({self.mode_a}), B = {self.b} ({self.mode_b})", "",
                 "| " + " | ".join(head) + " |", "|---|" + "---:|" * (len(head) - 1)]

        def cell(v: dict[str, Any]) -> str:
            def f(x: object) -> str:
                return f"{float(x):.2f}" if isinstance(x, int | float) else "–"  # type: ignore[arg-type]
            d = v["delta"]
            return f"{f(v['a'])} → {f(v['b'])} ({'+' if d is not None and d >= 0 else ''}{f(d)})"

        for row in self.table_rows():
            cells = [row["planner"], str(row["n"]), *[cell(row[key]) for _, key in keys],
                     f"{row['collides_only_a']} / {row['collides_only_b']}"]
            lines.append("| " + " | ".join(cells) + " |")
        return "\n".join(lines)


def compare_dirs(a: Path | str, b: Path | str) -> Comparison:
    """Compare two results directories (same dataset and metrics configuration; any modes)."""
    a, b = Path(a), Path(b)
    ia, ib = _run(a).get("identity", {}), _run(b).get("identity", {})
    for key, what in (("dataset_digest", "scenarios"), ("metrics_config", "metrics configuration")):
        if ia.get(key) != ib.get(key):
            raise ValueError(f"{a} and {b} hold results of other {what} ({key} differs): compare runs of the same "
                             "scenarios file under the same metrics configuration")
    ma, mb = read_metrics(a), read_metrics(b)
    common = [name for name in ma if name in mb]
    if not common:
        raise ValueError(f"{a} ({', '.join(ma) or 'none'}) and {b} ({', '.join(mb) or 'none'}) share no planner label")
    cmp = Comparison(a, b, str(ia.get("mode", "open-loop")), str(ib.get("mode", "open-loop")), common, ma, mb)
    for name in common:
        fa = load_planner_results(a, name)[["scenario_digest", "collision"]]
        fb = load_planner_results(b, name)[["scenario_digest", "collision"]]
        both = fa.merge(fb, on="scenario_digest", suffixes=("_a", "_b"))
        ca, cb = both["collision_a"].astype(bool), both["collision_b"].astype(bool)
        cmp.only_a[name] = both.loc[ca & ~cb, "scenario_digest"].astype(str).tolist()
        cmp.only_b[name] = both.loc[cb & ~ca, "scenario_digest"].astype(str).tolist()
        cmp.n_common[name] = len(both)
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
        picked = [(d, "collides in B only") for d in cmp.only_b[name][:n_examples]]
        picked += [(d, "collides in A only") for d in cmp.only_a[name][: n_examples - len(picked)]]
        if not picked:
            continue
        ra = _rows_by_digest(cmp.a, name, [d for d, _ in picked])
        rb = _rows_by_digest(cmp.b, name, [d for d, _ in picked])
        for digest, why in picked:
            rec_a, rec_b = ra.get(digest), rb.get(digest)
            if rec_a is None or rec_b is None or int(rec_b["row"]) >= n_file:
                continue
            sub = load_scenarios(scen, [int(rec_b["row"])])
            if str(scenario_digests(sub)[0]) != digest:
                continue
            top, bottom = stored_outcome(f"A: {cmp.mode_a}", sub, rec_a), stored_outcome(f"B: {cmp.mode_b}", sub, rec_b)
            caption = f"scenario {rec_b['scenario_id']}: {why}"
            fig = panel(sub, top, bottom, title=f"{name}: {caption}")
            out.setdefault(name, []).append((caption, figure_to_data_uri(fig, dpi=85)))
    return out


def write_comparison(a: Path | str, b: Path | str, out_dir: Path | str, *, n_examples: int = 3) -> Comparison:
    """``compare.md``, ``compare.json`` and ``compare.html`` in ``out_dir``; returns the comparison."""
    cmp = compare_dirs(a, b)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    text = cmp.markdown()
    atomic_write_text(out / "compare.md", text + "\n")
    payload = {"a": {"dir": str(cmp.a), "mode": cmp.mode_a}, "b": {"dir": str(cmp.b), "mode": cmp.mode_b},
               "planners": cmp.table_rows(),
               "collides_only_a": cmp.only_a, "collides_only_b": cmp.only_b}
    atomic_write_text(out / "compare.json", json.dumps(payload, indent=2, default=float) + "\n")
    panels = comparison_panels(cmp, n_examples)
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>letspi compare</title>"
             "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
             "td,th{border:1px solid #ccc;padding:3px 6px;text-align:right}img{max-width:100%}</style></head><body>",
             f"<h1>letspi compare</h1><p>A: <code>{html.escape(str(cmp.a))}</code> ({html.escape(cmp.mode_a)}); "
             f"B: <code>{html.escape(str(cmp.b))}</code> ({html.escape(cmp.mode_b)})</p>",
             "<table><tr><th>planner</th><th>n</th>"
             + "".join(f"<th>{html.escape(label)} A</th><th>B</th><th>Δ</th>" for label, _ in COMPARED)
             + "<th>collide only A</th><th>only B</th></tr>"]
    for row in cmp.table_rows():
        cells = [row["planner"], row["n"]]
        for _, key in COMPARED:
            cells += [row[key]["a"], row[key]["b"], row[key]["delta"]]
        cells += [row["collides_only_a"], row["collides_only_b"]]
        parts.append("<tr>" + "".join(
            f"<td>{html.escape(f'{c:.2f}' if isinstance(c, float) else ('–' if c is None else str(c)))}</td>"
            for c in cells) + "</tr>")
    parts.append("</table>")
    if not panels:
        parts.append("<p>No scenario changes its collision outcome (or the scenarios file was not found).</p>")
    for name, items in panels.items():
        parts.append(f"<h2>{html.escape(name)}: scenarios whose outcome differs</h2>")
        for caption, uri in items:
            parts.append(f"<figure><img src='{uri}' alt='{html.escape(caption)}'><figcaption>"
                         f"{html.escape(caption)}</figcaption></figure>")
    parts.append("</body></html>")
    atomic_write_text(out / "compare.html", "\n".join(parts) + "\n")
    return cmp
