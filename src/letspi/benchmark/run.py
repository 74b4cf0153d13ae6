"""Run a suite: its data (cached), every planner in each mode (a ``letspi evaluate`` directory per mode, resumed),
``leaderboard.{json,md,html}`` and ``timing.json``. A quick try (``limit``: the first N windows of each mode)
writes a leaderboard that says so, and the CLI puts it in a directory of its own, never the suite's."""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from letspi.assembly.planner_table import BUILT_IN
from letspi.assembly.planners import BuiltPlanner, build_planners, planner_kinds
from letspi.benchmark.data import SuiteData, prepare_data
from letspi.benchmark.leaderboard import leaderboard, mode_board, to_html, to_json, to_markdown
from letspi.benchmark.suites import REFERENCE_PLANNER, Mode, Suite
from letspi.evaluation.closed_loop import evaluate_closed_loop
from letspi.evaluation.harness import EvaluationSettings, ProgressFactory
from letspi.evaluation.harness import evaluate as evaluate_open_loop
from letspi.evaluation.results import ProgressCallback, reuse_line, reused_windows
from letspi.fsutil import atomic_write_text
from letspi.planners.mlp import MlpConfig
from letspi.planners.options import DEFAULT_OPTIONS, PlannerOptions
from letspi.scenario.identity import dataset_digest, scenario_digests
from letspi.scenario.split import vehicle_keys
from letspi.scenario.store import load_scenarios
from letspi.simulation.config import ClosedLoopConfig
from letspi.simulation.schedule import DualRateConfig
from letspi.suggest import did_you_mean
from letspi.viz.report import write_report


def default_planners() -> list[str]:
    """Every built-in planner that runs without a language model or files a default install lacks (``mlp``
    needs weights from ``letspi train mlp``), in the planner table's order."""
    return [k.name for k in BUILT_IN.kinds if not k.uses_llm and not issubclass(k.config_class, MlpConfig)]


@dataclass(frozen=True)
class SuiteRun:
    """What ``run_suite`` wrote and how long each stage took (wall seconds)."""

    out: Path
    board: dict[str, Any]
    data: SuiteData
    timing: dict[str, float]
    planner_s: dict[str, dict[str, float]] = field(default_factory=dict)


class _PlannerClock:
    """Wall time of each planner of one evaluation: ``evaluate`` asks the progress factory for a planner's
    progress when it starts that planner, so each request ends the previous planner's time."""

    def __init__(self, factory: ProgressFactory | None) -> None:
        self.factory = factory
        self.seconds: dict[str, float] = {}
        self._current: tuple[str, float] | None = None

    def __call__(self, name: str, total: int) -> ProgressCallback:
        self.stop()
        self._current = (name, time.perf_counter())
        return self.factory(name, total) if self.factory is not None else (lambda _n, _status: None)

    def stop(self) -> None:
        if self._current is not None:
            name, t0 = self._current
            self.seconds[name] = round(time.perf_counter() - t0, 2)
            self._current = None


def selected_modes(suite: Suite, slugs: Sequence[str] | None) -> tuple[Mode, ...]:
    """The suite's modes named by ``slugs`` (all when None or empty), in suite order; ValueError for an unknown slug."""
    if not slugs:
        return tuple(suite.modes)
    known = [m.slug for m in suite.modes]
    unknown = [s for s in slugs if s not in known]
    if unknown:
        raise ValueError(f"{suite.name} has no mode {', '.join(unknown)}{did_you_mean(unknown[0], known)} (its modes: "
                         f"{', '.join(known)})")
    return tuple(m for m in suite.modes if m.slug in slugs)


def closed_loop_settings(mode: Mode, workers: int, release: str = "checks") -> ClosedLoopConfig:
    """The suite mode's closed loop; ``release``: when a held preset gives way to the defaults (``RELEASE_MODES``)."""
    assert mode.replan_s is not None and mode.llm_period_s is not None
    return ClosedLoopConfig(mode=mode.mode, replan_s=mode.replan_s, workers=workers,  # type: ignore[arg-type]
                            dual_rate=DualRateConfig(mode.llm_period_s, mode.llm_latency_s, release=release))


def run_suite(suite: Suite, planner_args: Sequence[str], out: Path, *, options: PlannerOptions | None = None,
              highd_dir: Path | None = None, allow_other_files: bool = False, workers: int = 2,
              reports: bool = True, progress_factory: ProgressFactory | None = None,
              log: Callable[[str], None] = print, modes: Sequence[str] | None = None,
              limit: int | None = None, release: str = "checks") -> SuiteRun:
    """Make the data, evaluate ``planner_args`` (``KIND`` or ``LABEL=KIND``) in every mode (or those ``modes``
    names), write the leaderboard; ``limit``: only the first N windows of each mode (recorded as a quick try);
    ``release``: the closed-loop modes' release of held presets (``RELEASE_MODES``)."""
    if limit is not None and limit < 1:
        raise ValueError(f"--limit must be at least 1, got {limit}")
    out = Path(out)
    run_modes = selected_modes(suite, modes)
    if release != "checks" and all(m.mode == "open-loop" for m in run_modes):
        raise ValueError(f"--release {release} applies to the closed-loop modes only; the modes run here: "
                         + ", ".join(m.slug for m in run_modes))
    labels = [label for label, _ in planner_kinds(planner_args)]
    timing: dict[str, float] = {}
    started = time.perf_counter()
    data = prepare_data(suite, highd_dir=highd_dir, allow_other_files=allow_other_files, workers=workers, log=log)
    timing["generation_s"], timing["extraction_s"] = data.generation_s, data.extraction_s
    full = load_scenarios(data.scenarios_file)
    digests = scenario_digests(full)
    groups_of = dict(zip(digests.tolist(), vehicle_keys(full).tolist(), strict=True))
    planners: list[BuiltPlanner] = build_planners(list(planner_args), options or DEFAULT_OPTIONS)
    boards: dict[str, dict[str, Any]] = {}
    report_links: dict[str, str] = {}
    planner_s: dict[str, dict[str, float]] = {}  # mode -> planner -> wall seconds
    for mode in run_modes:
        eval_dir = out / mode.slug
        t0 = time.perf_counter()
        if mode.n_windows is not None and mode.n_windows < len(full):
            pick = np.random.default_rng(suite.extraction.seed).choice(len(full), mode.n_windows, replace=False)
            batch = full.take(np.sort(pick))
        else:
            batch = full
        if limit is not None:
            batch = batch.take(np.arange(min(limit, len(batch))))
        resumed = reuse_line(reused_windows(eval_dir, labels, batch), len(batch))
        if resumed:
            log(f"{mode.slug}: {resumed}")
        clock = _PlannerClock(progress_factory)
        if mode.mode == "open-loop":
            evaluate_open_loop(planners, batch, eval_dir, EvaluationSettings(
                scenarios_file=str(data.scenarios_file), metrics=suite.metrics, progress_factory=clock,
                workers=workers))
        else:
            evaluate_closed_loop(planners, batch, eval_dir, closed_loop_settings(mode, workers, release),
                                 scenarios_file=str(data.scenarios_file), config=suite.metrics, progress_factory=clock)
        clock.stop()
        timing[f"{mode.slug}_s"] = time.perf_counter() - t0
        if mode.mode != "open-loop" or workers <= 1:  # open-loop planners in workers are timed as one stage
            planner_s[mode.slug] = clock.seconds
        reference = REFERENCE_PLANNER if REFERENCE_PLANNER in labels else None
        boards[mode.slug] = mode_board(eval_dir, labels, groups_of, reference)
        if reports:
            t0 = time.perf_counter()
            write_report(eval_dir, with_diagrams=False, config=suite.metrics)
            report_links[mode.slug] = f"{mode.slug}/report.html"
            timing[f"{mode.slug}_report_s"] = time.perf_counter() - t0
    board = leaderboard(suite, boards, dataset_digest(digests), data.file_digests, limit=limit)
    atomic_write_text(out / "leaderboard.json", to_json(board))
    atomic_write_text(out / "leaderboard.md", to_markdown(board))
    atomic_write_text(out / "leaderboard.html", to_html(board, report_links))
    timing["total_s"] = time.perf_counter() - started
    record = {"suite": suite.suite_id, "planners": labels, "data_reused": data.reused, "workers": workers,
              "limit": limit, "load_average_end": list(np.round(os.getloadavg(), 2)),
              **{k: round(v, 2) for k, v in timing.items()}, "planner_s": planner_s}
    atomic_write_text(out / "timing.json", json.dumps(record, indent=2) + "\n")
    return SuiteRun(out=out, board=board, data=data, timing=timing, planner_s=planner_s)
