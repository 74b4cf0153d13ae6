"""The Python API: load scenarios, build planners, plan, evaluate, and read the results as DataFrames, over the same
keyed, resumable harness as the CLI (docs/your-planner.md)::

    import letspi.api as lp
    batch = lp.load_scenarios("data/scenarios.arrow", limit=300)
    planners = lp.planners("sf", "frenet", goals="kinematic")   # KIND, LABEL=KIND or pkg.mod:NAME; planner options
    results = lp.evaluate(planners, batch, "runs/mine")         # rerun: resumes, adds planners
    lp.evaluate(["sf", MyPlanner()], batch, "runs/other")       # names and planner objects are taken too
    print(results.table())                # metrics.md: values with 95 % intervals, paired with sf
    results.summary(), results.per_scenario("frenet"), results.paired_summary()   # DataFrames

    plan = lp.plan(planners[0], batch.take(range(5)))           # a PlanBatch: (B, F, 2) positions ...

``open_results(DIR)`` reads any results directory (``letspi evaluate --out DIR``); docs/evaluation.md.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeAlias

import numpy as np
import pandas as pd

from letspi.assembly.planner_table import add_planner_paths, planner_table
from letspi.assembly.planners import BuiltPlanner, build_planners, built_from_object, planner_kinds
from letspi.evaluation.closed_loop import evaluate_closed_loop
from letspi.evaluation.harness import EvaluationSettings
from letspi.evaluation.harness import evaluate as run_evaluation
from letspi.evaluation.results import load_planner_results, read_summary
from letspi.evaluation.summary import summary_markdown
from letspi.metrics.aggregate import TABLE_COLUMNS
from letspi.metrics.config import MetricsConfig
from letspi.planners.base import PlanBatch, Planner
from letspi.planners.options import PlannerOptions
from letspi.scenario.store import count_scenarios
from letspi.scenario.store import load_scenarios as _load
from letspi.scenario.types import ScenarioBatch
from letspi.simulation.config import ClosedLoopConfig

__all__ = ["ClosedLoopConfig", "PlanBatch", "PlannerLike", "Results", "ScenarioBatch", "evaluate", "load_scenarios",
           "open_results", "plan", "planners"]

#: what ``evaluate`` and ``plan`` take as a planner: a spec (``"sf"``, ``"LABEL=KIND"``, ``"pkg.mod:NAME"``), a
#: planner of ``planners(...)``, or a planner object (``plan(batch)``, ``name``, ``batch_size``) given as it is
PlannerLike: TypeAlias = BuiltPlanner | Planner | str
#: directories to import ``pkg.mod:NAME`` kinds from (``--planner-path``)
PathsLike: TypeAlias = str | Path | Sequence[str | Path] | None

#: the metrics of ``Results.summary`` by default: the paper's table (``letspi.metrics.aggregate.TABLE_COLUMNS``)
SUMMARY_KEYS: tuple[str, ...] = tuple(key for _, key in TABLE_COLUMNS)


def load_scenarios(path: str | Path, *, limit: int | None = None,
                   rows: Sequence[int] | np.ndarray | None = None) -> ScenarioBatch:
    """Scenarios of a ``letspi data scenarios`` file (digests checked): all, the first ``limit``, or ``rows``."""
    if limit is not None and rows is not None:
        raise ValueError("give limit or rows, not both")
    if limit is not None:
        if limit < 0:
            raise ValueError(f"limit must be >= 0, got {limit}")
        rows = np.arange(min(limit, count_scenarios(Path(path))))
    return _load(Path(path), None if rows is None else np.asarray(rows, dtype=np.int64))


def planners(*specs: str, planner_path: PathsLike = None, **options: Any) -> list[BuiltPlanner]:
    """Build planners from ``KIND``, ``LABEL=KIND`` or ``package.module:NAME`` specs (``letspi planners`` lists the
    kinds; a module is imported from the working directory, ``planner_path`` or the Python path) with planner options by
    the words of their flags (``neighbours="idm"`` for ``--neighbours``, ``sf_params=...``, ``goals="kinematic"``; the
    option names, ``neighbour_mode=``, work too; ``letspi planners --json`` lists them). Models load once, here."""
    if not specs:
        raise ValueError("name at least one planner, e.g. planners('sf')")
    add_planner_paths(_paths(planner_path))
    bad = [s for s in specs if not isinstance(s, str)]
    if bad:
        raise TypeError(f"planners() takes specs ('sf', 'LABEL=KIND', 'pkg.mod:NAME'), got {type(bad[0]).__name__}; "
                        "evaluate() and plan() take planner objects as they are")
    planner_kinds(list(specs))  # kinds named by import path join the table, with their options
    return build_planners(list(specs), PlannerOptions.from_keywords(planner_table().options(), **options))


def _paths(paths: PathsLike) -> list[str | Path]:
    if paths is None:
        return []
    return [paths] if isinstance(paths, str | Path) else list(paths)


def as_built(items: PlannerLike | Iterable[PlannerLike], **options: Any) -> list[BuiltPlanner]:
    """Planners as the harness runs them, from ``PlannerLike`` items in order: specs built together by ``planners``
    with ``options``, built planners kept, planner objects through ``letspi.assembly.planners.built_from_object``."""
    listed: list[Any] = [items] if isinstance(items, str | BuiltPlanner) or _is_planner(items) else list(
        items)  # type: ignore[arg-type]
    specs = [item for item in listed if isinstance(item, str)]
    if options and not specs:
        raise ValueError(f"planner options ({', '.join(options)}) apply to planners given by name; pass them to "
                         "lp.planners(...) or give the planners as names")
    from_specs = iter(planners(*specs, **options) if specs else [])
    out = []
    for item in listed:
        if isinstance(item, str):
            out.append(next(from_specs))
        elif isinstance(item, BuiltPlanner):
            out.append(item)
        elif _is_planner(item):
            out.append(built_from_object(item))
        else:
            raise TypeError(f"a planner is a name ('sf', 'LABEL=KIND', 'pkg.mod:NAME'), a planner of lp.planners(...) "
                            f"or an object with plan(batch), a name and a batch_size; got {type(item).__name__}")
    labels = [b.name for b in out]
    dup = sorted({x for x in labels if labels.count(x) > 1})
    if dup:
        raise ValueError(f"planner label(s) {', '.join(dup)} given twice; give variants their own label "
                         "('LABEL=KIND', or the object's name)")
    return out


def _is_planner(obj: object) -> bool:
    return not isinstance(obj, str | BuiltPlanner | type) and callable(getattr(obj, "plan", None))


def plan(planner: PlannerLike, batch: ScenarioBatch) -> PlanBatch:
    """The plans (untimed, unscored) of one planner for ``batch``, given the history only unless its kind reads the
    recorded future (an oracle; a planner object whose ``reads_future`` is true)."""
    (built,) = as_built(planner)
    return built.planner.plan(batch if built.reads_future else batch.history())


def evaluate(planners: PlannerLike | Iterable[PlannerLike], scenarios: ScenarioBatch | str | Path, out: str | Path,
             *, limit: int | None = None, reference: str | None = None, metrics_config: MetricsConfig | None = None,
             closed_loop: ClosedLoopConfig | None = None, **options: Any) -> Results:
    """Evaluate ``planners`` (names are built with ``options`` as ``planners`` does) on ``scenarios`` (a batch, or a
    scenario file with an optional ``limit``) into the results directory ``out``, as ``letspi evaluate`` does: keyed,
    resumable, planners of earlier calls kept. ``reference``: the planner the others are compared with (default
    ``sf`` when present). Open loop unless ``closed_loop`` is given, e.g. ``ClosedLoopConfig(mode="closed-loop-log",
    replan_s=0.2)`` (``closed-loop-hybrid`` here without scripted neighbours). Returns the directory's ``Results``."""
    built = as_built(planners, **options)
    if closed_loop is not None and closed_loop.workers and any(b.config.kind == "object" for b in built):
        raise ValueError("planner objects run in this process: closed loop with workers=0, or give the planner a "
                         "PlannerKind (docs/your-planner.md) so that worker processes can build it")
    if isinstance(scenarios, ScenarioBatch):
        if limit is not None:
            raise ValueError("limit applies to a scenario file; pass batch.take(...) instead")
        batch, source = scenarios, ""
    else:
        batch, source = load_scenarios(scenarios, limit=limit), str(scenarios)
    if closed_loop is not None:
        evaluate_closed_loop(built, batch, Path(out), closed_loop, scenarios_file=source,
                             config=metrics_config, reference=reference)
    else:
        run_evaluation(built, batch, Path(out), EvaluationSettings(
            scenarios_file=source, metrics=metrics_config or MetricsConfig(), reference=reference))
    return open_results(out)


def open_results(directory: str | Path) -> Results:
    """The results of a results directory (``letspi evaluate --out DIR`` or ``evaluate``)."""
    directory = Path(directory)
    return Results(directory, read_summary(directory))


@dataclass(frozen=True)
class Results:
    """One results directory: its ``metrics.json`` and its per-window rows, as Python values and DataFrames."""

    directory: Path
    raw: dict[str, Any]

    def __repr__(self) -> str:
        return f"Results({str(self.directory)!r}, planners={self.planners}, reference={self.reference!r})"

    @property
    def planners(self) -> list[str]:
        """Planner labels, in the order of metrics.json."""
        return list(self.raw.get("planners", {}))

    @property
    def metrics(self) -> dict[str, dict[str, Any]]:
        """{planner: {metrics.json key: value}} (``letspi.metrics.aggregate`` and timing keys)."""
        return dict(self.raw.get("planners", {}))

    @property
    def intervals(self) -> dict[str, dict[str, list[float] | None]]:
        """{planner: {key: [low, high] or None}}: the 95 % intervals of every rate and mean."""
        return dict(self.raw.get("intervals", {}))

    @property
    def reference(self) -> str | None:
        """The planner the others are compared with (None with fewer than two planners)."""
        paired = self.raw.get("paired")
        return str(paired["reference"]) if isinstance(paired, dict) else None

    @property
    def run(self) -> dict[str, Any]:
        """What the results are keyed by: mode, dataset digest, metrics configuration, dataset."""
        return dict(self.raw.get("run", {}))

    def _check(self, name: str) -> None:
        if name not in self.raw.get("planners", {}):
            raise KeyError(f"{self.directory} has no planner {name!r} (it has: {', '.join(self.planners) or 'none'})")

    def per_scenario(self, name: str, *, with_plans: bool = False) -> pd.DataFrame:
        """One planner's stored rows, in dataset order: ``scenario_id``, ``scenario_digest``, ``row``,
        ``vehicle_key``, every per-window metric (docs/metrics-reference.md), ``inference_s`` and the
        planner's declared outputs (``letspi.planners.outputs.column``); ``with_plans`` adds the plans."""
        self._check(name)
        return load_planner_results(self.directory, name, with_plans=with_plans)

    def summary(self, keys: Sequence[str] = SUMMARY_KEYS) -> pd.DataFrame:
        """One row per planner (index ``planner``), for each key three columns: ``key``, ``key_low`` and
        ``key_high`` (the 95 % interval; NaN where a key has none), plus ``n``."""
        rows = []
        for name, agg in self.metrics.items():
            row: dict[str, Any] = {"planner": name, "n": agg.get("n")}
            for key in keys:
                interval = self.intervals.get(name, {}).get(key)
                value = agg.get(key)
                row[key] = np.nan if value is None else value
                row[f"{key}_low"], row[f"{key}_high"] = interval if interval else (np.nan, np.nan)
            rows.append(row)
        return pd.DataFrame(rows).set_index("planner") if rows else pd.DataFrame()

    def paired_summary(self, keys: Sequence[str] = SUMMARY_KEYS) -> pd.DataFrame:
        """One row per planner and key compared with the reference: ``n_pairs``, ``diff`` (planner minus
        reference), ``diff_low``/``diff_high`` (95 %), and for rates ``n_only_planner``,
        ``n_only_reference``, ``n_both`` and ``p_mcnemar`` (NaN for means). Empty without a reference."""
        paired = self.raw.get("paired") or {}
        rows = []
        for name, entries in (paired.get("planners") or {}).items():
            for key in keys:
                rec = entries.get(key)
                if rec is None:
                    continue
                low, high = rec.get("diff_ci95") or (None, None)
                rows.append({"planner": name, "reference": paired.get("reference"), "key": key,
                             "n_pairs": rec.get("n_pairs"), "diff": rec.get("diff"), "diff_low": low, "diff_high": high,
                             **{c: rec.get(c, np.nan) for c in ("n_only_planner", "n_only_reference", "n_both",
                                                                "p_mcnemar")}})
        return pd.DataFrame(rows).astype({"diff": float, "diff_low": float, "diff_high": float}) if rows else (
            pd.DataFrame())

    def table(self, names: Sequence[str] | None = None) -> str:
        """The Markdown tables of metrics.md (values with intervals, the paired comparison) for ``names``."""
        return summary_markdown(self.raw, names)

    def report(self, out: str | Path | None = None, *, n_worst: int = 3, with_diagrams: bool = True) -> Path:
        """Write the self-contained HTML report (default ``DIR/report.html``) and return its path."""
        from letspi.viz.report import write_report  # plotting loads here, not with letspi.api

        return write_report(self.directory, out, n_worst=n_worst, with_diagrams=with_diagrams)
