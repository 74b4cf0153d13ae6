"""highway-env's benchmark suites (``SUITES``, the ``letspi.suites`` entry point) and their runner.

A suite pins the environment, its configuration, the seeds, the timing and highway-env's and gymnasium's versions
(their digests pinned in ``tests/test_highway_env_run.py``). Its results directory is a
``letspi_interop.highway_env.store`` directory plus ``suite.json``, ``timing.json`` and ``report.html``; a rerun
resumes and more planners join. A run refuses installed highway-env or gymnasium versions other than the suite's.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Final

from letspi.benchmark.run import default_planners
from letspi.benchmark.suites import REFERENCE_PLANNER, Pinned
from letspi.fsutil import atomic_write_text
from letspi.metrics.config import MetricsConfig
from letspi.planners.options import PlannerOptions
from letspi.simulation.schedule import DualRateConfig
from letspi_interop.highway_env import INSTALL_HINT, require
from letspi_interop.highway_env.report import write_episode_report
from letspi_interop.highway_env.run import ProgressFactory, build_drivers, driver_name, run_episodes
from letspi_interop.highway_env.settings import NATIVE_EGOS, EnvSettings, installed_versions

#: the versions the highway-env suites pin (the extra ``highway``)
HIGHWAY_ENV_VERSIONS: Final = (("gymnasium", "1.4.0"), ("highway-env", "1.12.1"))
#: DiLu's evaluation seeds (DiLu, ICLR 2024, its released configuration)
DILU_SEEDS: Final = (5838, 2421, 7294, 9650, 4176, 6382, 8765, 1348, 4213, 2572)
#: DiLu's highway-v0 setting (the issue's reading of DiLu's configuration): 50 vehicles, ego spacing 4, 30 s
_DILU_CONFIG: Final = (("duration", 30), ("ego_spacing", 4), ("simulation_frequency", 15), ("vehicles_count", 50))


def _seeds(n: int, first: int) -> tuple[int, ...]:
    """DiLu's ten seeds, then ``first``, ``first + 1``, ... up to ``n`` seeds."""
    return DILU_SEEDS + tuple(range(first, first + n - len(DILU_SEEDS)))


@dataclass(frozen=True)
class HighwayEnvSuite(Pinned):
    """One suite in highway-env: episodes of ``env_id`` with ``config`` (over highway-env's defaults), one per
    seed, at most ``duration_s`` long; planners replan every ``replan_s`` (highway-env's policy period), LLM
    planners ask their model every ``llm_period_s`` with a fixed answer latency ``llm_latency_s``.
    ``published``: what the literature reports on it (docs/highway-env.md); ``sizing``: the power argument."""

    name: str
    version: int
    description: str
    env_id: str
    config: tuple[tuple[str, Any], ...]
    seeds: tuple[int, ...]
    published: str
    sizing: str
    duration_s: float = 30.0
    replan_s: float = 0.2
    llm_period_s: float = 2.5
    llm_latency_s: float = 1.5
    versions: tuple[tuple[str, str], ...] = HIGHWAY_ENV_VERSIONS
    metrics: MetricsConfig = field(default_factory=MetricsConfig)

    def __post_init__(self) -> None:
        if len(set(self.seeds)) != len(self.seeds) or not self.seeds:
            raise ValueError(f"{self.name}: seeds must be distinct, got {self.seeds}")

    def definition(self) -> dict[str, Any]:
        """Everything that makes a result of this suite (what the digest is computed over)."""
        return {"name": self.name, "version": self.version, "simulator": "highway-env", "env_id": self.env_id,
                "config": dict(self.config), "seeds": list(self.seeds), "duration_s": self.duration_s,
                "replan_s": self.replan_s, "llm_period_s": self.llm_period_s, "llm_latency_s": self.llm_latency_s,
                "versions": dict(self.versions), "metrics": self.metrics.recorded(), "reference": REFERENCE_PLANNER}

    def list_lines(self) -> list[str]:
        return [f"{self.suite_id:34s} {len(self.seeds):>6,d} episodes highway-env {self.env_id}",
                f"    {self.description}; published: {self.published}"]

    def show_lines(self) -> list[str]:
        return [f"{self.suite_id}: {self.description}",
                f"environment: {self.env_id} {json.dumps(dict(self.config), sort_keys=True)}; {self.duration_s:g} s "
                f"episodes; replanning every {self.replan_s:g} s; LLM planners ask their model every "
                f"{self.llm_period_s:g} s, answers in force after {self.llm_latency_s:g} s",
                f"versions: {', '.join(f'{k} {v}' for k, v in self.versions)}",
                f"seeds ({len(self.seeds)}): {', '.join(map(str, self.seeds))}",
                f"published: {self.published}",
                f"size: {self.sizing}"]

    def run(self, planners: Sequence[str] | None, out: Path, *, options: PlannerOptions, workers: int,
            reports: bool, progress: ProgressFactory, log: Callable[[str], None]) -> str:
        """Every planner (default: the benchmark's and highway-env's own egos) on every seed; metrics.md."""
        run_highway_env_suite(self, planners or default_highway_env_planners(default_planners()), out,
                              options=options, workers=workers, reports=reports, progress=progress, log=log)
        return (out / "metrics.md").read_text() + f"\nresults in {out}/ (metrics.json, metrics.md, report.html, " \
            "timing.json)"


_HE_SIZING = ("{n} episodes: a success rate near 70 % is known to about ±9 points (95 % Wilson interval); two "
              "planners that disagree on 30 % of the episodes and differ by 15 (20) points are told apart by exact "
              "McNemar (alpha 0.05) with power {p15} ({p20}) (letspi benchmark power --discordance-pct 30 "
              "--difference-pts 15)")

def _dilu_five_lanes(density: float, first_seed: int, published: str) -> HighwayEnvSuite:
    """One of DiLu's generalisation settings: highway-v0 with 5 lanes at ``density``, 50 episodes."""
    return HighwayEnvSuite(
        name=f"highway-env-dilu-5lane-{density:g}", version=1,
        description=f"DiLu's generalisation: highway-v0 with 5 lanes at density {density:g} (else as "
                    "highway-env-dilu); DiLu's 10 seeds and 40 more",
        env_id="highway-v0", config=(("lanes_count", 5), ("vehicles_density", density), *_DILU_CONFIG),
        seeds=_seeds(50, first_seed), published=published, sizing=_HE_SIZING.format(n=50, p15="0.41", p20="0.70"))


#: the table of highway-env suites (one entry per suite; the ``letspi.suites`` entry point)
SUITES: Final[Mapping[str, HighwayEnvSuite]] = MappingProxyType({s.name: s for s in (
    HighwayEnvSuite(
        name="highway-env-dilu", version=1,
        description="highway-v0 as DiLu evaluates it: 4 lanes, density 2, 50 vehicles, ego spacing 4, 30 s, 15 Hz "
                    "simulation; replanning every 0.2 s; DiLu's 10 seeds and 90 more",
        env_id="highway-v0", config=(("lanes_count", 4), ("vehicles_density", 2), *_DILU_CONFIG),
        seeds=_seeds(100, 20001),
        published="DiLu (40 memories) 70 % success, GRAD (an RL baseline) 69 % (as DiLu, ICLR 2024, reports them)",
        sizing=_HE_SIZING.format(n=100, p15="0.75", p20="0.96")),
    _dilu_five_lanes(2.5, 20101, "DiLu 65 % success, GRAD 47 %"),
    _dilu_five_lanes(3, 20201, "DiLu 35 % success, GRAD 10 %"),
    HighwayEnvSuite(
        name="highway-env-merge", version=1,
        description="merge-v0 (highway-env's defaults: 2 lanes and an on-ramp, 4 other vehicles), 15 Hz "
                    "simulation; an episode ends once the ramp is passed, at the latest after 30 s; 50 seeds",
        env_id="merge-v0", config=(("simulation_frequency", 15),), seeds=tuple(range(20301, 20351)),
        published="no LLM-driving paper reports merge-v0 with these settings",
        sizing=_HE_SIZING.format(n=50, p15="0.41", p20="0.70")),
)})


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
