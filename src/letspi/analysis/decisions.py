"""What deciding planners decided, and what it bought (``letspi analyze decisions``): every planner of one or more
results directories paired with a reference (default ``sf``) on shared windows, pooled."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from letspi.constants import N_FUTURE
from letspi.evaluation.results import load_planner_results, stored_vehicles
from letspi.evaluation.summary import cached
from letspi.metrics.stats import paired_rate, wilson_interval
from letspi.planners.decision import CONSULTED, DECISION
from letspi.planners.outputs import column as output_column

RATES = (("collision", "CR"), ("collision_at_fault", "CR at fault"), ("success", "SR"))


def _progress(frame: pd.DataFrame) -> np.ndarray:
    """(n,) the x of each stored plan's last frame [m] (ego frame: the progress along the road)."""
    return np.array([np.asarray(p, dtype=np.float64).reshape(N_FUTURE, 2)[-1, 0] for p in frame["plan_xy_m"]])


@dataclass(frozen=True)
class Paired:
    """One planner's rows paired with the reference's, pooled over directories (n,) each."""

    planner: pd.DataFrame
    reference: pd.DataFrame
    groups: np.ndarray
    sources: np.ndarray


def paired_rows(directories: Sequence[Path], name: str, reference: str) -> Paired:
    """Rows of ``name`` and ``reference`` on the windows both hold, per directory, pooled."""
    mine, ref, groups, sources = [], [], [], []
    for d in directories:
        a = load_planner_results(d, name, with_plans=True)
        b = load_planner_results(d, reference, with_plans=True)
        if not len(a) or not len(b):
            raise ValueError(f"{d}: needs stored results of both {name!r} and {reference!r}")
        shared = sorted(set(a["scenario_digest"]) & set(b["scenario_digest"]))
        a = a.set_index("scenario_digest").loc[shared].reset_index()
        b = b.set_index("scenario_digest").loc[shared].reset_index()
        mine.append(a)
        ref.append(b)
        vehicles, _ = stored_vehicles(a)
        groups.append(np.char.add(f"{d}/", vehicles.astype(str)))
        sources.append(np.full(len(a), str(d)))
    return Paired(pd.concat(mine, ignore_index=True), pd.concat(ref, ignore_index=True),
                  np.concatenate(groups), np.concatenate(sources))


def planner_report(p: Paired, name: str, reference: str) -> dict[str, Any]:
    """The figures of the module docstring for one planner against the reference."""
    a, b = p.planner, p.reference
    n = len(a)
    out: dict[str, Any] = {"planner": name, "reference": reference, "n": n}
    for column, label in RATES:
        flags = np.asarray(a[column], dtype=bool)
        ref_flags = np.asarray(b[column], dtype=bool)
        low, high = wilson_interval(int(flags.sum()), n)
        pr = paired_rate(flags, ref_flags, p.groups)
        out[label] = {"pct": 100 * flags.mean(), "ci95": [100 * low, 100 * high],
                      "reference_pct": 100 * ref_flags.mean(), "only_planner": pr.n_only_a,
                      "only_reference": pr.n_only_b, "both": pr.n_both, "p_mcnemar": pr.p_mcnemar,
                      "ratio": float(flags.mean() / ref_flags.mean()) if ref_flags.any() else float("nan")}
    prog, ref_prog = _progress(a), _progress(b)
    out["progress_m"] = {"mean": float(prog.mean()), "reference_mean": float(ref_prog.mean()),
                         "diff_pct": float(100 * (prog.mean() / ref_prog.mean() - 1.0))}
    if output_column(DECISION) in a:
        decision = a[output_column(DECISION)].astype(str).to_numpy()
        ref_collides = np.asarray(b["collision"], dtype=bool)
        kept = decision == "default"
        col = output_column(CONSULTED)
        consulted = np.asarray(a[col], dtype=bool) if col in a else np.ones(n, bool)
        live = ~cached(a)
        t = np.asarray(a["inference_s"], dtype=np.float64)
        counts = pd.Series(decision).value_counts()
        out["decisions"] = {
            "shares_pct": {str(k): float(100 * v / n) for k, v in sorted(counts.items())},
            "distinct_at_least_2pct": int((counts / n >= 0.02).sum()),
            "keep_where_reference_safe_pct": float(100 * kept[~ref_collides].mean()) if (~ref_collides).any()
            else float("nan"),
            "change_where_reference_collides_pct": float(100 * (~kept)[ref_collides].mean()) if ref_collides.any()
            else float("nan"),
            "consulted_pct": float(100 * consulted.mean()),
            "median_s_all": float(np.median(t[live])) if live.any() else float("nan"),
            "median_s_consulted": float(np.median(t[live & consulted])) if (live & consulted).any() else float("nan"),
            "live_rows": int(live.sum()),
        }
    return out


def decisions_markdown(reports: Sequence[dict[str, Any]]) -> str:
    """One table of the rates (with the paired counts) and one of the decisions."""
    lines = ["| planner | n | CR % | CR at fault % (ratio to ref; only planner / only ref, p) | SR % (ref) | "
             "progress m (vs ref) |", "|---|---:|---:|---:|---:|---:|"]
    for r in reports:
        f, s, c = r["CR at fault"], r["SR"], r["CR"]
        lines.append(f"| {r['planner']} | {r['n']} | {c['pct']:.2f} | {f['pct']:.2f} [{f['ci95'][0]:.2f}, "
                     f"{f['ci95'][1]:.2f}] (x{f['ratio']:.2f}; {f['only_planner']} / {f['only_reference']}, "
                     f"p = {f['p_mcnemar']:.2g}) | {s['pct']:.2f} ({s['reference_pct']:.2f}) | "
                     f"{r['progress_m']['mean']:.1f} ({r['progress_m']['diff_pct']:+.2f} %) |")
    deciding = [r for r in reports if "decisions" in r]
    if deciding:
        lines += ["", "| planner | decisions (% of windows) | kept where ref safe % | changed where ref collides % | "
                  "consulted % | median s (all / consulted) |", "|---|---|---:|---:|---:|---:|"]
        for r in deciding:
            d = r["decisions"]
            shares = ", ".join(f"{k} {v:.1f}" for k, v in d["shares_pct"].items())
            lines.append(f"| {r['planner']} | {shares} | {d['keep_where_reference_safe_pct']:.1f} | "
                         f"{d['change_where_reference_collides_pct']:.1f} | {d['consulted_pct']:.1f} | "
                         f"{d['median_s_all']:.3f} / {d['median_s_consulted']:.3f} |")
    return "\n".join(lines)
