"""Run a highway-env suite (``letspi.benchmark.suites.HIGHWAY_ENV_SUITES``): its seeds, every planner, the table.

Layout of the results directory: a ``letspi.evaluation.highway_env.store`` directory (``run.json``,
``episodes/<label>/``, ``metrics.json``, ``metrics.md``) plus ``suite.json`` (the suite's id and definition),
``timing.json`` (wall time per label, load average) and ``report.html``. Rerunning resumes where it stopped; more
planners join. A run refuses installed highway-env or gymnasium versions other than the suite's.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from letspi.benchmark.suites import REFERENCE_PLANNER, HighwayEnvSuite
from letspi.evaluation.highway_env.run import ProgressFactory, build_drivers, driver_name, run_episodes
from letspi.evaluation.highway_env.settings import NATIVE_EGOS, EnvSettings, installed_versions
from letspi.fsutil import atomic_write_text
from letspi.interop.highway_env import INSTALL_HINT, require
from letspi.planners.options import PlannerOptions
from letspi.simulation.schedule import DualRateConfig
from letspi.viz.highway_env import write_episode_report


def suite_settings(suite: HighwayEnvSuite) -> EnvSettings:
    return EnvSettings(suite.env_id, suite.config, suite.duration_s, suite.replan_s,
                       DualRateConfig(suite.llm_period_s, suite.llm_latency_s))


def check_versions(suite: HighwayEnvSuite) -> None:
    """Refuse installed highway-env / gymnasium versions other than the suite's, in one line."""
    require()
    installed = installed_versions()
    wrong = {name: (want, installed.get(name)) for name, want in suite.versions if installed.get(name) != want}
    if wrong:
        what = ", ".join(f"{name} {have} (the suite pins {want})" for name, (want, have) in wrong.items())
        raise ValueError(f"{suite.name} needs other versions: {what}; {INSTALL_HINT}")


def default_highway_env_planners(planners: Sequence[str]) -> list[str]:
    """``planners`` (the benchmark's defaults) and highway-env's own egos."""
    return [*planners, *NATIVE_EGOS]


def run_highway_env_suite(suite: HighwayEnvSuite, planner_args: Sequence[str], out: Path, *,
                          options: PlannerOptions | None = None, workers: int = 2, reports: bool = True,
                          progress: ProgressFactory | None = None,
                          log: Callable[[str], None] = print) -> dict[str, Any]:
    """Every planner on every seed of ``suite`` into ``out`` (resumable); returns the metrics.json record."""
    check_versions(suite)
    out = Path(out)
    drivers = build_drivers(planner_args, options)
    labels = [driver_name(d) for d in drivers]
    started = time.perf_counter()
    clock: dict[str, float] = {}
    current: list[tuple[str, float]] = []

    def stop() -> None:
        if current:
            label, t0 = current.pop()
            clock[label] = round(time.perf_counter() - t0, 2)

    def timed(name: str, total: int) -> Callable[[int], None]:
        stop()
        current.append((name, time.perf_counter()))
        return progress(name, total) if progress is not None else (lambda _k: None)

    atomic_write_text(out / "suite.json", json.dumps({"id": suite.suite_id, **suite.definition()}, indent=2) + "\n")
    record = run_episodes(drivers, suite_settings(suite), suite.seeds, out, workers=workers, config=suite.metrics,
                          reference=REFERENCE_PLANNER, progress=timed)  # paired with sf when it is stored
    stop()
    if reports:
        log(f"report: {write_episode_report(out)}")
    timing = {"suite": suite.suite_id, "planners": labels, "workers": workers, "label_s": clock,
              "total_s": round(time.perf_counter() - started, 2), "load_average_end": [round(x, 2) for x in
                                                                                       os.getloadavg()]}
    atomic_write_text(out / "timing.json", json.dumps(timing, indent=2) + "\n")
    return record
