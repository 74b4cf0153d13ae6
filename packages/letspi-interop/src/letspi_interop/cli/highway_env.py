"""``letspi highway-env``: run planners on highway-env episodes (``run``); export an episode as HighD (``export``).

The pinned suites run through ``letspi benchmark run highway-env-dilu`` (``letspi benchmark list``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer

from letspi.assembly.planner_table import planner_table
from letspi.cli.common import command_line, console, progress_bar, user_errors
from letspi.cli.options import planner_options
from letspi.fsutil import writer_lock
from letspi.highd.io import write_recording
from letspi.planners.options import PlannerOptions
from letspi.simulation.schedule import DualRateConfig
from letspi_interop.highway_env import require
from letspi_interop.highway_env.run import build_drivers, run_episodes
from letspi_interop.highway_env.scene import episode_recording
from letspi_interop.highway_env.settings import NATIVE_DOCS, EnvSettings
from letspi_interop.highway_env.store import labels, load_episode, load_episodes

app = typer.Typer(help="letspi on highway-env: episodes with any planner; episodes as HighD recordings.",
                  no_args_is_help=True, rich_markup_mode=None)

NATIVE_HELP = "; ".join(f"{name}: {doc}" for name, doc in NATIVE_DOCS.items())


def parse_settings(values: list[str] | None) -> dict[str, Any]:
    """``KEY=VALUE`` pairs, each value JSON (``4``, ``2.5``, ``true``, ``[1, 2]``) or else a string."""
    out: dict[str, Any] = {}
    for text in values or []:
        key, sep, value = text.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"--set takes KEY=VALUE, got {text!r}")
        try:
            out[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            out[key.strip()] = value
    return out


def _progress(bar: Any) -> Any:
    def factory(name: str, total: int) -> Any:
        task = bar.add_task(name, total=total)
        return lambda k: bar.advance(task, k)

    return factory


@app.command("run")
@planner_options()
def run(
    options: PlannerOptions,
    out: Annotated[Path, typer.Option(help="Results directory (resumable; one environment setting per directory).")],
    planner: Annotated[list[str] | None, typer.Option(
        help="Planner (repeatable; KIND or LABEL=KIND). " + planner_table().planner_help() + " highway-env's own "
             f"egos: {NATIVE_HELP}.")] = None,
    env: Annotated[str, typer.Option(help="highway-env environment: highway-v0, highway-fast-v0 or merge-v0.")] = (
        "highway-v0"),
    set_: Annotated[list[str] | None, typer.Option(
        "--set", help="highway-env configuration KEY=VALUE over its defaults (repeatable), e.g. lanes_count=4.")
    ] = None,
    seed: Annotated[list[int] | None, typer.Option(help="Episode seed (repeatable).")] = None,
    n_seeds: Annotated[int, typer.Option(help="Without --seed: seeds 0 .. N-1.")] = 10,
    duration_s: Annotated[float, typer.Option(help="The episode ends at the latest after this many seconds.")] = 30.0,
    replan_s: Annotated[float, typer.Option(help="Replanning period (highway-env's policy period) [s].")] = 0.2,
    llm_period_s: Annotated[float, typer.Option(help="LLM planners: model asked every this many seconds.")] = 2.5,
    llm_latency_s: Annotated[float, typer.Option(
        help="LLM planners: answers in force this many seconds after the call (fixed: reproducible).")] = 1.5,
    workers: Annotated[int, typer.Option(min=0, help="Worker processes (0 or 1: this process).")] = 2,
    reference: Annotated[str | None, typer.Option(
        help="Label every other is paired with (default: sf if it runs).")] = None,
) -> None:
    """Run each planner on each seed's episode (highway-env seeded, letspi's ego swapped in, replanning every
    --replan-s), then metrics.json / metrics.md with 95 % intervals and paired tests."""
    with user_errors(resumes=True) as tally:
        require()
        settings = EnvSettings(env, tuple(parse_settings(set_).items()), duration_s, replan_s,
                               DualRateConfig(llm_period_s, llm_latency_s))
        seeds = list(seed) if seed else list(range(n_seeds))
        drivers = build_drivers(planner or ["sf", "he-idm"], options)
        names = [d.name for d in drivers]
        ref = reference or ("sf" if "sf" in names else None)
        tally.track(len(seeds) * len(drivers), lambda: sum(len(load_episodes(out, n)) for n in labels(out)))
        with writer_lock(out, command_line()), progress_bar() as bar:
            record = run_episodes(drivers, settings, seeds, out, workers=workers, reference=ref,
                                  progress=_progress(bar))
    typer.echo((out / "metrics.md").read_text())
    console.print(f"{len(record['planners'])} planners on {len(seeds)} seeds; results in {out}/ (metrics.json, "
                  "metrics.md; `letspi report` draws an episode of each)")


@app.command("export")
def export(
    results: Annotated[Path, typer.Argument(help="A highway-env results directory (letspi highway-env run).")],
    planner: Annotated[str, typer.Option(help="The label whose episode is exported.")],
    seed: Annotated[int, typer.Option(help="The episode's seed.")],
    out: Annotated[Path, typer.Option(help="HighD directory to write NN_*.csv into.")],
    recording_id: Annotated[int, typer.Option(min=1, max=99, help="The recording's NN.")] = 1,
) -> None:
    """Write a stored episode as a HighD recording (25 Hz, every vehicle): `letspi data info` and `letspi data
    scenarios` read it, so the open-loop protocol runs on highway-env traffic."""
    with user_errors():
        tracks, road, _, _ = load_episode(results, planner, seed)
        paths = write_recording(episode_recording(tracks, road, recording_id), out)
    for path in paths:
        typer.echo(str(path))
