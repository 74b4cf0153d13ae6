"""The paper's Tables III-VI on the pinned suites, one resumable run (``letspi benchmark paper``; the layout of
``OUT`` is in docs/reproduction.md).

Each suite's windows are split by ego vehicle (seeded) into a memory share, on which the memory phase collects,
and the rest, from which the evaluated windows are drawn and pooled. Every table is an ordinary evaluation
directory or an ablation preset (``letspi.evaluation.ablations``), so resumable and keyed as those are."""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np

from letspi.assembly.build import Builder
from letspi.assembly.planners import BuiltPlanner, build_planner, resolve_planner
from letspi.benchmark.data import prepare_data
from letspi.benchmark.suites import get_suite
from letspi.evaluation.ablations import (
    COMPONENT_ROWS,
    FS_ROW,
    collect_memories,
    combination_row,
    memory_size_row,
    run_ablation,
)
from letspi.evaluation.harness import EvaluationSettings, ProgressFactory, evaluate
from letspi.evaluation.results import load_planner_results, read_summary
from letspi.fsutil import atomic_write_text
from letspi.metrics.config import MetricsConfig
from letspi.planners.llm import FAST_LLM, LLM, LLM_CACHE, LLM_CALLS, LLM_ORIGINAL_LATENCY, MEMORY, PROMPT_STYLE
from letspi.planners.options import PlannerOptions
from letspi.planners.outputs import column
from letspi.scenario.identity import dataset_digest, scenario_digests
from letspi.scenario.split import split_by_vehicle, subsample
from letspi.scenario.store import load_scenarios, save_scenarios
from letspi.scenario.types import ScenarioBatch, concat_batches

TABLES: Final = ("III", "IV", "V", "VI")
DEFAULT_SUITES: Final = ("stress-closed-loop", "on-ramp-critical", "lane-drop-critical")
#: the embedded models (docs/llm.md): SmolLM2-135M with the shipped adapter, without it, and Gemma-3-270M
MEMORY_MODELS: Final = ("llamacpp:smollm2-135m-letspi", "llamacpp:gemma3-270m")
FAST_MODELS: Final = ("llamacpp:smollm2-135m-letspi", "llamacpp:smollm2-135m", "llamacpp:gemma3-270m")
#: Table V's fractions of Base's memories (the paper: 0-80 % of 10,000 windows; 1.0 is Base itself)
PAPER_FRACTIONS: Final = (0.0, 0.01, 0.1, 0.5, 0.8, 1.0)
BASELINES: Final = ("sf", "idm", "gnp", "frenet", "sf-check")
FAST_ROW, MEMORY_ROW = "LetsPi_F", "LetsPi_M"
REFERENCE: Final = "sf"

#: the paper's columns: (letspi's metrics.json key, label)
COLUMNS: Final = (("ttc_s", "TTC s"), ("cr_pct", "CR %"), ("pet_s", "PET s"), ("min_dist_m", "minD m"),
                  ("lt_pct", "LT %"), ("sr_pct", "SR %"))
#: letspi's columns: the paper's and CR at fault beside CR (then the model's share and time, ``_llm_figures``)
LETSPI_COLUMNS: Final = (("ttc_s", "TTC s"), ("cr_pct", "CR %"), ("cr_at_fault_pct", "CR at fault %"),
                         ("pet_s", "PET s"), ("min_dist_m", "minD m"), ("lt_pct", "LT %"), ("sr_pct", "SR %"))
#: the paired tests shown (rates: windows only the row / only the reference has the event, McNemar p)
PAIRED: Final = (("cr_at_fault_pct", "CR at fault"), ("sr_pct", "SR"))

#: the paper's numbers (TTC s, CR %, PET s, minD m, LT %, SR %, inference s) by row, Tables III-V; Table III's
#: "4,13" is read as 4.13 and its fast row, labelled LetsPi_D, is the fast phase (REFERENCE.md section 7)
PAPER_III: Final[Mapping[str, tuple[float, ...]]] = {
    "SF": (4.13, 8.9, 1.31, 17.12, 11.5, 100.0, 0.1), "IDM": (3.94, 15.1, 0.92, 13.49, 10.1, 100.0, 0.1),
    "GNP": (4.01, 8.7, 1.50, 16.82, 10.0, 100.0, 0.1), "LetsPi_M": (5.90, 2.8, 2.80, 16.75, 6.0, 97.0, 6.18),
    "LetsPi_D": (5.98, 3.4, 2.65, 17.92, 8.0, 99.6, 3.12)}
PAPER_IV: Final[Mapping[str, tuple[float, ...]]] = {
    "w/o Ref": (4.33, 8.0, 1.84, 16.77, 11.0, 99.7), "w/o GA": (4.18, 4.7, 1.86, 17.01, 10.7, 99.7),
    "FS": (3.71, 9.7, 1.59, 17.25, 11.1, 99.8), "Base": (5.98, 3.4, 2.65, 17.92, 8.0, 99.6)}
PAPER_V: Final[Mapping[str, tuple[float, ...]]] = {
    "0 (0%)": (3.71, 9.7, 1.59, 17.25, 11.1, 99.8), "100 (1%)": (3.67, 11.0, 1.67, 16.79, 15.8, 99.3),
    "1000 (10%)": (4.18, 6.5, 2.25, 17.85, 9.2, 99.5), "5000 (50%)": (5.77, 4.8, 2.46, 17.93, 8.5, 99.5),
    "8000 (80%)": (5.98, 3.4, 2.65, 17.92, 8.0, 99.6)}
#: Table VI: (memory model, its s, fast model, its s, TTC, CR, PET, minD, LT, SR)
PAPER_VI: Final[tuple[tuple[Any, ...], ...]] = (
    ("deepseek-r1:14b", 17.92, "llama3.1:8B", 5.35, 6.13, 2.4, 3.20, 16.98, 5.7, 93.5),
    ("deepseek-r1:14b", 18.36, "llama3.2:3B", 3.07, 6.01, 3.0, 3.15, 18.07, 6.0, 93.7),
    ("deepseek-r1:14b", 18.05, "deepseek-r1:1.5b", 3.16, 5.71, 3.1, 2.25, 17.32, 7.8, 89.0),
    ("llama3.1:8B", 6.34, "llama3.1:8B", 5.38, 5.97, 2.8, 2.79, 17.34, 7.4, 99.1),
    ("llama3.1:8B", 6.18, "llama3.2:3B", 3.12, 5.98, 3.4, 2.65, 17.92, 8.0, 99.6),
    ("llama3.1:8B", 6.15, "deepseek-r1:1.5b", 3.36, 5.61, 3.2, 2.45, 17.80, 8.2, 95.0))


@dataclass(frozen=True)
class PaperSettings:
    """What a paper run pins; per suite: ``eval_windows`` evaluated, ``memory_windows`` collected on,
    ``memory_phase_windows`` of the evaluated ones also planned by ``letspi-memory``; ``memory_share``: share of
    each suite's ego vehicles whose windows are held for collection."""

    suites: tuple[str, ...] = DEFAULT_SUITES
    eval_windows: int = 800
    memory_windows: int = 100
    memory_phase_windows: int = 50
    memory_share: float = 0.3
    seed: int = 0
    memory_models: tuple[str, ...] = MEMORY_MODELS
    fast_models: tuple[str, ...] = FAST_MODELS
    prompt_style: str = "choice"

    def __post_init__(self) -> None:
        if not self.suites:
            raise ValueError("a paper run needs at least one suite")
        if min(self.eval_windows, self.memory_windows) < 1 or not 0 <= self.memory_phase_windows <= self.eval_windows:
            raise ValueError("--windows and --memory-windows must be >= 1, --memory-phase-windows in [0, --windows]")
        if not 0.0 < self.memory_share < 1.0:
            raise ValueError(f"--memory-share must be in (0, 1), got {self.memory_share}")


@dataclass(frozen=True)
class PaperData:
    """The pooled windows (module docstring) and the files they were written to."""

    eval: ScenarioBatch
    memory: ScenarioBatch
    memory_phase: ScenarioBatch
    files: dict[str, Path]
    config: MetricsConfig
    suite_ids: tuple[str, ...]


@dataclass
class PaperRun:
    """What ``run_paper`` wrote: the report's tables, and the wall seconds of each stage."""

    out: Path
    tables: dict[str, Any]
    timing: dict[str, float] = field(default_factory=dict)


def split_suite(batch: ScenarioBatch, settings: PaperSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row indices (eval, memory, memory phase) of one suite's windows: vehicles split by ``memory_share``,
    then each side subsampled (seeded) to its size; the memory-phase rows are a subset of the eval rows."""
    memory_pool, eval_pool = split_by_vehicle(batch, settings.memory_share, settings.seed)
    rng = np.random.default_rng(settings.seed)
    evaluated = subsample(eval_pool, settings.eval_windows, rng)
    memory = subsample(memory_pool, settings.memory_windows, rng)
    phase = subsample(evaluated, settings.memory_phase_windows, rng) if settings.memory_phase_windows else evaluated[:0]
    return evaluated, memory, phase


def paper_data(settings: PaperSettings, out: Path, *, workers: int = 2,
               log: Callable[[str], None] = print) -> PaperData:
    """The suites' data (cached), split and pooled into ``OUT/data`` (a file there must hold the same windows)."""
    parts: dict[str, list[ScenarioBatch]] = {"eval": [], "memory": [], "memory-phase": []}
    configs: list[MetricsConfig] = []
    ids = []
    for name in settings.suites:
        suite = get_suite(name)
        data = prepare_data(suite, workers=workers, log=log)
        batch = load_scenarios(data.scenarios_file)
        for key, rows in zip(parts, split_suite(batch, settings), strict=True):
            parts[key].append(batch.take(rows))
        configs.append(suite.metrics)
        ids.append(suite.suite_id)
    if len({c.key() for c in configs}) != 1:
        raise ValueError(f"suites {', '.join(settings.suites)} score under different metrics configurations: "
                         "they cannot be pooled into one table")
    pooled = {key: concat_batches(batches) for key, batches in parts.items() if batches}
    files: dict[str, Path] = {}
    for key, batch in pooled.items():
        path = out / "data" / f"{key}.arrow"
        digest = dataset_digest(scenario_digests(batch))
        if path.exists():
            stored = dataset_digest(scenario_digests(load_scenarios(path)))
            if stored != digest:
                raise ValueError(f"{path} holds other windows (digest {stored}, this run's {digest}): "
                                 "use another --out")
        else:
            save_scenarios(batch, path, {"paper_suites": ids, "paper_part": key})
        files[key] = path
    return PaperData(pooled["eval"], pooled["memory"], pooled["memory-phase"], files, configs[0], tuple(ids))


def _check_settings(out: Path, record: dict[str, Any]) -> None:
    """Write ``OUT/settings.json`` or refuse a run whose settings differ from the stored ones."""
    path = out / "settings.json"
    record = json.loads(json.dumps(record))  # tuples as the stored lists
    if path.exists():
        stored = json.loads(path.read_text())
        diff = sorted(k for k in set(stored) | set(record) if stored.get(k) != record.get(k))
        if diff:
            raise ValueError(f"{out} holds a paper run with other settings ({', '.join(diff)}): use another --out")
        return
    atomic_write_text(path, json.dumps(record, indent=2, sort_keys=True) + "\n")


def run_paper(settings: PaperSettings, out: Path, options: PlannerOptions, *, tables: Sequence[str] = TABLES,
              workers: int = 2, progress_factory: ProgressFactory | None = None,
              log: Callable[[str], None] = print, data: PaperData | None = None) -> PaperRun:
    """Run the tables ``tables`` (each stage resumes) and write the report. ``options``: the planners' options
    (``--memory`` defaults to OUT/memory.sqlite, the prompt style to ``settings.prompt_style``); ``data``: the pooled
    windows (default: ``paper_data``)."""
    unknown = [t for t in tables if t not in TABLES]
    if unknown:
        raise ValueError(f"unknown table {', '.join(unknown)}; available: {', '.join(TABLES)}")
    out = Path(out)
    started = time.perf_counter()
    timing: dict[str, float] = {}
    data = data or paper_data(settings, out, workers=workers, log=log)
    timing["data_s"] = time.perf_counter() - started
    options = options.replace(memory=options.get(MEMORY) or out / "memory.sqlite",
                              prompt_style=options.get(PROMPT_STYLE) or settings.prompt_style)
    _check_settings(out, _pinned(settings, data, options))
    builder = Builder(cache="default" if options.get(LLM_CACHE) else None)
    common: dict[str, Any] = {"progress_factory": progress_factory, "builder": builder, "config": data.config,
                              "collect_batch": data.memory, "scenarios_file": str(data.files["eval"])}

    def stage(name: str, fn: Callable[[], object]) -> None:
        t0 = time.perf_counter()
        log(f"paper: {name}")
        fn()
        timing[f"{name}_s"] = round(time.perf_counter() - t0, 2)

    def built(kind: str, name: str, opts: PlannerOptions) -> BuiltPlanner:
        return build_planner(resolve_planner(kind, opts), name, builder=builder)

    # Base's memories first: every table's LetsPi_F retrieves from them
    base_key = _base_collection(options, data, out, builder, stage)
    base = options.replace(memory_key=base_key)
    if "III" in tables:
        def table_iii() -> None:
            rows = [built(k, k, base) for k in BASELINES] + [built("letspi-fast", FAST_ROW, base)]
            evaluate(rows, data.eval, out / "table-iii", EvaluationSettings(
                scenarios_file=str(data.files["eval"]), progress_factory=progress_factory, workers=workers,
                reference=REFERENCE, metrics=data.config))
            if len(data.memory_phase):
                rows = [built("sf", REFERENCE, base), built("letspi-fast", FAST_ROW, base),
                        built("letspi-memory", MEMORY_ROW, base)]
                evaluate(rows, data.memory_phase, out / "table-iii-memory-phase", EvaluationSettings(
                    scenarios_file=str(data.files["memory-phase"]), progress_factory=progress_factory,
                    reference=REFERENCE, metrics=data.config))
        stage("table_iii", table_iii)
    if "IV" in tables:
        stage("table_iv", lambda: run_ablation("components", data.eval, out, base, reference=COMPONENT_ROWS[0][0],
                                               **common))
    if "V" in tables:
        stage("table_v", lambda: run_ablation("memory-size", data.eval, out, base, fractions=PAPER_FRACTIONS,
                                              reference=memory_size_row(1.0), **common))
    if "VI" in tables:
        combos = combinations(settings, options)
        stage("table_vi", lambda: run_ablation("llm-combinations", data.eval, out, base, combinations=combos,
                                               reference=combination_row(*combos[0]), **common))
    report = _write_report(out, settings, options)
    timing["total_s"] = round(time.perf_counter() - started, 2)
    _write_timing(out, timing, tables)
    return PaperRun(out, report, timing)


def _pinned(settings: PaperSettings, data: PaperData, options: PlannerOptions) -> dict[str, Any]:
    """What ``settings.json`` pins: the settings, the suites' ids, the models, the prompt style, the data."""
    batches = (("eval", data.eval), ("memory", data.memory), ("memory-phase", data.memory_phase))
    return {**asdict(settings), "suite_ids": list(data.suite_ids), "llm": options.get(LLM),
            "fast_llm": options.get(FAST_LLM), "prompt_style": options.get(PROMPT_STYLE),
            "datasets": {k: dataset_digest(scenario_digests(b)) for k, b in batches}}


def _write_report(out: Path, settings: PaperSettings, options: PlannerOptions) -> dict[str, Any]:
    report = paper_tables(out, settings, options)
    atomic_write_text(out / "paper.json", json.dumps(report, indent=2, sort_keys=True, default=float) + "\n")
    atomic_write_text(out / "paper.md", paper_markdown(report))
    return report


def combinations(settings: PaperSettings, options: PlannerOptions) -> list[tuple[str, str]]:
    """Table VI's (memory model, fast model) pairs, Base's pair first (the table's reference)."""
    first = (options.get(LLM), options.get(FAST_LLM))
    pairs = [(m, f) for m in settings.memory_models for f in settings.fast_models]
    return [first, *(p for p in pairs if p != first)]


def _base_collection(options: PlannerOptions, data: PaperData, out: Path, builder: Builder,
                     stage: Callable[[str, Callable[[], object]], None]) -> str:
    """Collect Base's memories (the full memory phase, resumable) as the components preset does; their key."""
    keys: list[str] = []
    stage("collect_base", lambda: keys.append(collect_memories(options, data.memory, builder, None,
                                                               out / "ablations")))
    return keys[0]


def _write_timing(out: Path, timing: Mapping[str, float], tables: Sequence[str]) -> None:
    path = out / "timing.json"
    runs = json.loads(path.read_text())["runs"] if path.exists() else []
    runs.append({"tables": list(tables), **{k: round(v, 2) for k, v in timing.items()},
                 "load_average_end": [round(x, 2) for x in os.getloadavg()]})
    atomic_write_text(path, json.dumps({"runs": runs}, indent=2) + "\n")


# the report ------------------------------------------------------------------------------------------
def _llm_figures(directory: Path, name: str) -> dict[str, float | None]:
    """The model's share and cost in one row's results: ``consulted_pct`` (windows it was asked on) and ``call_s``
    (median seconds of one call over the windows that made calls, as first made: the cache does not hide it)."""
    frame = load_planner_results(directory, name)
    calls_column, latency_column = column(LLM_CALLS), column(LLM_ORIGINAL_LATENCY)
    if frame.empty or calls_column not in frame:
        return {"consulted_pct": None, "call_s": None}
    calls = frame[calls_column].to_numpy(np.float64)
    asked = calls > 0
    per_call = frame[latency_column].to_numpy(np.float64)[asked] / calls[asked]
    return {"consulted_pct": float(100.0 * asked.mean()),
            "call_s": float(np.median(per_call)) if per_call.size else None}


def _row(summary: Mapping[str, Any], name: str, directory: Path) -> dict[str, Any] | None:
    """One row of a results directory: each shown metric with its interval, the model's share and cost, and
    the paired tests against the directory's reference (None when the row has no results)."""
    values = summary.get("planners", {}).get(name)
    if values is None:
        return None
    intervals = summary.get("intervals", {}).get(name, {})
    metrics = {k: {"value": values.get(k), "ci95": intervals.get(k)} for k, _ in LETSPI_COLUMNS}
    row: dict[str, Any] = {"n": values.get("n"), "metrics": metrics, "llm": _llm_figures(directory, name)}
    paired = summary.get("paired", {})
    entry = paired.get("planners", {}).get(name)
    if entry is not None:
        row["paired"] = {"reference": paired.get("reference"), **{k: entry.get(k) for k, _ in PAIRED}}
    return row


class _Results:
    """One results directory's ``metrics.json`` (empty when absent) and its rows (``_row``)."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self.summary = read_summary(directory) if (directory / "metrics.json").exists() else {}

    def row(self, name: str) -> dict[str, Any] | None:
        return _row(self.summary, name, self.directory)

    def n(self) -> int | None:
        planners = self.summary.get("planners", {})
        return next((int(p["n"]) for p in planners.values()), None) if planners else None


def paper_tables(out: Path, settings: PaperSettings, options: PlannerOptions) -> dict[str, Any]:
    """The four tables from the results directories under ``out`` (rows without results are left out)."""
    iii, phase = _Results(out / "table-iii"), _Results(out / "table-iii-memory-phase")
    abl = out / "ablations"
    comp, size, combos = (_Results(abl / k) for k in ("components", "memory-size", "llm-combinations"))
    paper_rows = {"sf": "SF", "idm": "IDM", "gnp": "GNP", FAST_ROW: "LetsPi_D"}
    t3 = [{"row": n, "paper": PAPER_III.get(paper_rows.get(n, "")), "letspi": iii.row(n)}
          for n in (*BASELINES, FAST_ROW)]
    t3_phase = [{"row": n, "paper": PAPER_III["LetsPi_M"] if n == MEMORY_ROW else None, "letspi": phase.row(n)}
                for n in (REFERENCE, FAST_ROW, MEMORY_ROW)]
    t4 = [{"row": n, "paper": PAPER_IV[n], "letspi": comp.row(n)}
          for n in (*(name for name, _ in COMPONENT_ROWS[1:]), FS_ROW, COMPONENT_ROWS[0][0])]
    paper_v = list(PAPER_V.values())
    t5 = [{"row": memory_size_row(f), "paper": paper_v[i] if i < len(paper_v) else None,
           "letspi": size.row(memory_size_row(f))} for i, f in enumerate(PAPER_FRACTIONS)]
    t6 = [{"row": combination_row(m, f), "memory": m, "fast": f, "letspi": combos.row(combination_row(m, f))}
          for m, f in combinations(settings, options)]
    collections_file = abl / "collections.json"
    collections = json.loads(collections_file.read_text()) if collections_file.exists() else {}
    return {"settings": asdict(settings), "III": t3, "III_memory_phase": t3_phase, "IV": t4, "V": t5,
            "VI": t6, "VI_paper": [list(r) for r in PAPER_VI], "collections": collections,
            "n_windows": {"III": iii.n(), "III_memory_phase": phase.n()}}


def _num(value: Any, digits: int = 2) -> str:
    return "–" if value is None or not np.isfinite(float(value)) else f"{float(value):.{digits}f}"


def _cell(metric: Mapping[str, Any] | None) -> str:
    if not metric or metric.get("value") is None:
        return "–"
    ci = metric.get("ci95")
    text = _num(metric["value"])
    return text + (f" ({_num(ci[0])}–{_num(ci[1])})" if ci and None not in ci else "")


def _paired_cell(entry: Mapping[str, Any] | None) -> str:
    if not entry or entry.get("n_only_planner") is None:
        return "–"
    p = entry.get("p_mcnemar")
    return (f"{entry['diff']:+.2f}: {entry['n_only_planner']} / {entry['n_only_reference']}, "
            f"p {p:.2g}" if p is not None else f"{entry['diff']:+.2f}")


def _paper_cell(values: Sequence[float] | None) -> str:
    return "–" if values is None else " / ".join(f"{v:g}" for v in values[:6])


def _table(rows: Sequence[Mapping[str, Any]], reference: str, paper: bool = True) -> list[str]:
    header = ["row"] + (["paper: TTC / CR / PET / minD / LT / SR"] if paper else [])
    header += [label for _, label in LETSPI_COLUMNS] + ["model asked %", "s per call"]
    header += [f"{label} vs {reference}: Δ pts: only row / only {reference}, p" for _, label in PAIRED]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in rows:
        got = r.get("letspi")
        cells = [str(r["row"])] + ([_paper_cell(r.get("paper"))] if paper else [])
        if got is None:
            cells += ["not run"] + [""] * (len(header) - len(cells) - 1)
        else:
            cells += [_cell(got["metrics"].get(k)) for k, _ in LETSPI_COLUMNS]
            llm = got.get("llm", {})
            cells += [_num(llm.get("consulted_pct"), 1), _num(llm.get("call_s"))]
            paired = got.get("paired")
            cells += [_paired_cell(paired.get(k) if paired else None) if paired else "reference" for k, _ in PAIRED]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def paper_markdown(report: Mapping[str, Any]) -> str:
    """``paper.md``: the four tables (the paper's numbers, letspi's with 95 % intervals, paired tests)."""
    s = report["settings"]
    n = report["n_windows"]
    lines = ["# The paper's Tables III-VI, measured by letspi", "",
             f"Suites {', '.join(s['suites'])}: {s['eval_windows']} evaluated windows each "
             f"({n.get('III') or '–'} pooled), memories collected on {s['memory_windows']} windows each of other "
             f"vehicles, letspi-memory on {s['memory_phase_windows']} of the evaluated windows each; prompt style "
             f"{s['prompt_style']}; seed {s['seed']}. Open loop.", "",
             "Paper columns: TTC / CR / PET / minD / LT / SR. letspi: TTC is the mean of min(TTC, 10 s); CR all "
             "contacts (box overlap); CR at fault only those the ego caused; PET over finite values; minD centre to "
             "centre; 95 % intervals in brackets (windows grouped by ego vehicle). Model asked: the windows the "
             "model was called on; s per call: the median time of one call as it was first made (the paper's "
             "inference time per scenario, Table III: SF, IDM, GNP 0.1 s, LetsPi_M 6.18 s, LetsPi_D 3.12 s). "
             "Paired: the difference in points, the windows only the row / only the reference has the event, "
             "exact McNemar p.", "",
             "## Table III: comparison", ""]
    lines += _table(report["III"], REFERENCE)
    lines += ["", f"The memory phase on {n.get('III_memory_phase') or '–'} of the evaluated windows:", ""]
    lines += _table(report["III_memory_phase"], REFERENCE)
    lines += ["", "## Table IV: components (letspi-fast over memories collected by each variant)", ""]
    lines += _table(report["IV"], "Base")
    lines += ["", "## Table V: memory size (share of Base's memories; the paper's rows 0-80 % of 10,000)", ""]
    lines += _table(report["V"], memory_size_row(1.0))
    lines += ["", "## Table VI: LLM combinations", "", "The paper (memory model, s; fast model, s; TTC / CR / PET / "
              "minD / LT / SR):", ""]
    lines += [f"- {r[0]} ({r[1]:g} s) + {r[2]} ({r[3]:g} s): {' / '.join(f'{v:g}' for v in r[4:])}"
              for r in report["VI_paper"]]
    lines += ["", "letspi (the memory model collects, the fast model plans):", ""]
    lines += _table(report["VI"], "the first row", paper=False)
    if report.get("collections"):
        lines += ["", "Memory collections (wall seconds per scenario when they ran; model calls, of which cached):", ""]
        for key, c in sorted(report["collections"].items()):
            per = c["seconds"] / c["scenarios"] if c["scenarios"] else float("nan")
            lines.append(f"- `{key}` {c['model']}: {c['scenarios']} scenarios, {_num(per)} s each, "
                         f"{c['calls']} calls ({c['cached_calls']} cached)")
    return "\n".join(lines) + "\n"
