"""Run planners and highway-env's own egos over the seeds of an environment, into a results directory.

Each label (a planner built by ``letspi.assembly``, or a ``NativeEgo``) runs the seeds not yet stored
(``store.EpisodeWriter``): in this process (``workers`` <= 1; the planner built by the caller is used as is) or in
``workers`` spawned processes (``letspi.execution.interrupt.WorkerPool``: they ignore Ctrl-C and are terminated
when the run stops; each builds its planner once from its configuration). This process is the only writer: an
episode is stored as it arrives, so a stopped run keeps every finished episode and a rerun runs the rest.
Planners that read the recorded future (``human``, the oracle modes) are refused: an episode has none.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from letspi.assembly.planners import BuiltPlanner, build_planners, parse_planner_arg
from letspi.evaluation.results import planner_record
from letspi.execution.interrupt import WorkerPool
from letspi.metrics.config import MetricsConfig
from letspi.planners.base import Planner
from letspi.planners.options import DEFAULT_OPTIONS, PlannerOptions
from letspi.simulation.spec import PlannerSpec, build_planner
from letspi_interop.highway_env.episode import EpisodePlanner, EpisodeResult, run_episode
from letspi_interop.highway_env.settings import NATIVE_EGOS, RUN_MODE, EnvSettings, NativeEgo
from letspi_interop.highway_env.store import EpisodeWriter, open_run, summarise

Driver = BuiltPlanner | NativeEgo
#: (label, episodes in all) -> a callback told how many more are done
ProgressFactory = Callable[[str, int], Callable[[int], None]]


def driver_name(driver: Driver) -> str:
    return driver.name


def evaluation_of(settings: EnvSettings, dual_rate: bool) -> dict[str, Any]:
    """What joins a planner's key: the mode and replanning period; for an LLM planner its dual-rate timing."""
    out: dict[str, Any] = {"mode": RUN_MODE, "replan_s": round(settings.replan_s, 6)}
    if dual_rate:
        out["dual_rate"] = settings.dual_rate.identity(releasing=False)  # episodes do not release presets
    return out


def driver_record(driver: Driver, settings: EnvSettings) -> dict[str, Any]:
    """``config.json`` of a label's results."""
    if isinstance(driver, NativeEgo):
        return driver.record()
    return planner_record(driver, evaluation_of(settings, driver.dual_rate))


def check_drivers(drivers: Sequence[Driver]) -> None:
    """Refuse planners that read the recorded future, and duplicate labels, in one line."""
    names = [driver_name(d) for d in drivers]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"label(s) given twice: {', '.join(twice)}")
    for d in drivers:
        if isinstance(d, BuiltPlanner) and d.reads_future:
            raise ValueError(f"planner {d.name!r} reads the recorded future (an upper bound, not a planner); a "
                             "highway-env episode has none")


@dataclass(frozen=True)
class EpisodeTask:
    """One episode for a worker: the settings, the seed, and who drives (a planner by its configuration, whether
    it runs dual-rate, or a highway-env ego)."""

    settings: EnvSettings
    seed: int
    config: MetricsConfig
    spec: PlannerSpec | None = None
    dual_rate: bool = False
    native: NativeEgo | None = None


#: a worker's planners, built once per process (key, label) -> planner
_WORKER_PLANNERS: dict[tuple[str, str], Planner] = {}


def _episode_planner(planner: Planner, settings: EnvSettings, dual_rate: bool) -> EpisodePlanner:
    return EpisodePlanner(planner, settings.dual_rate if dual_rate else None)


def run_task(task: EpisodeTask) -> EpisodeResult:
    """A worker's episode (its planner built on first use)."""
    if task.native is not None:
        return run_episode(task.settings, task.seed, ego_kind=task.native.kind, config=task.config)
    assert task.spec is not None
    key = (task.spec.config.key(), task.spec.name)
    if key not in _WORKER_PLANNERS:
        _WORKER_PLANNERS[key] = build_planner(task.spec)
    planner = _episode_planner(_WORKER_PLANNERS[key], task.settings, task.dual_rate)
    return run_episode(task.settings, task.seed, planner=planner, config=task.config)


def episode_results(driver: Driver, settings: EnvSettings, seeds: Sequence[int], *, workers: int,
                    config: MetricsConfig) -> Iterator[EpisodeResult]:
    """The episodes of ``driver`` on ``seeds``, as they finish (in seed order in this process)."""
    if workers <= 1:
        for seed in seeds:
            if isinstance(driver, NativeEgo):
                yield run_episode(settings, seed, ego_kind=driver.kind, config=config)
            else:
                yield run_episode(settings, seed, planner=_episode_planner(driver.planner, settings, driver.dual_rate),
                                  config=config)
        return
    native = driver if isinstance(driver, NativeEgo) else None
    spec = None if isinstance(driver, NativeEgo) else PlannerSpec.of_built(driver)
    dual = False if isinstance(driver, NativeEgo) else driver.dual_rate
    with WorkerPool(min(workers, max(len(seeds), 1))) as pool:
        futures = [pool.submit(run_task, EpisodeTask(settings, int(s), config, spec, dual, native)) for s in seeds]
        for future in as_completed(futures):
            yield future.result()


def run_episodes(drivers: Sequence[Driver], settings: EnvSettings, seeds: Sequence[int], out: Path, *,
                 workers: int = 2, config: MetricsConfig | None = None, reference: str | None = None,
                 progress: ProgressFactory | None = None) -> dict[str, Any]:
    """Every driver on every seed (the stored ones skipped), then ``metrics.json`` / ``metrics.md`` over ``seeds``
    paired with ``reference`` (a label, when it ran). Returns the metrics.json record."""
    config = config or MetricsConfig()
    check_drivers(drivers)
    if len(set(seeds)) != len(seeds):
        raise ValueError("seeds must be distinct")
    open_run(out, settings, config)
    for driver in drivers:
        writer = EpisodeWriter(out, driver_record(driver, settings))
        done = writer.done()
        todo = [int(s) for s in seeds if int(s) not in done]
        tick = progress(driver_name(driver), len(seeds)) if progress is not None else None
        if tick is not None and len(seeds) - len(todo):
            tick(len(seeds) - len(todo))
        for result in episode_results(driver, settings, todo, workers=workers, config=config):
            writer.write(result)
            if tick is not None:
                tick(1)
    return summarise(out, seeds, reference, config)


def build_drivers(planner_args: Sequence[str], options: PlannerOptions | None = None) -> list[Driver]:
    """``KIND`` / ``LABEL=KIND`` arguments as drivers, in order: highway-env's egos (``NATIVE_EGOS``) as
    ``NativeEgo``, every other kind built by ``letspi.assembly`` (one builder: models loaded once)."""
    parsed = [parse_planner_arg(a) for a in planner_args]
    planners = [a for a, (_, kind) in zip(planner_args, parsed, strict=True) if kind not in NATIVE_EGOS]
    built = iter(build_planners(planners, options or DEFAULT_OPTIONS) if planners else [])
    return [NativeEgo.of(label, kind) if kind in NATIVE_EGOS else next(built) for label, kind in parsed]
