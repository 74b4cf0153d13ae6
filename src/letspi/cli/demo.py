"""``letspi demo``: the main job on the embedded default (generated data)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from letspi.cli.common import console, progress_bar, user_errors


def demo(
    out: Annotated[Path, typer.Option(help="Working directory for all demo outputs.")] = Path("letspi-demo"),
    minutes: Annotated[float, typer.Option(help="Simulated minutes of traffic to generate.")] = 3.0,
    seed: int = 0,
    max_scenarios: Annotated[int, typer.Option(help="Scenarios to sample and evaluate.")] = 1000,
) -> None:
    """The main job: generate (or reuse) SUMO traffic as HighD files, extract planning scenarios,
    evaluate the baselines (human, cv, idm, sf, sf-opt) and print the paper-style table.

    The shipped ``sf`` parameters were fitted on traffic generated with seed 1; the demo's
    default seed 0 keeps its scenarios held out from that fit. Rerunning reuses finished work.
    """
    from letspi.highd.io import list_recording_ids, read_recordings
    from letspi.scenario.extract import extract_scenarios
    from letspi.scenario.store import save_scenarios
    from letspi.sumo.generate import generate_recordings

    highd_dir = out / "highd"
    scenarios_file = out / "scenarios.arrow"
    with user_errors():
        if highd_dir.exists() and list_recording_ids(highd_dir):
            console.print(f"reusing recordings in {highd_dir}")
        else:
            with progress_bar() as bar:
                task = bar.add_task("simulating (SUMO)", total=100.0)
                generate_recordings(
                    highd_dir, minutes=minutes, seed=seed,
                    progress=lambda f: bar.update(task, completed=100.0 * f),
                )
        recs = read_recordings(highd_dir)
        with progress_bar() as bar:
            task = bar.add_task("extracting scenarios", total=None)
            batch = extract_scenarios(
                recs, max_scenarios=max_scenarios, seed=seed, progress=lambda k: bar.advance(task, k)
            )
        save_scenarios(batch, scenarios_file, extra_meta={"provenance": {"source": str(highd_dir), "seed": seed}})
        console.print(f"[green]{len(batch)} scenarios[/green] from {len(recs)} recording(s) -> {scenarios_file}")

        from letspi.evaluation.harness import evaluate
        from letspi.metrics.aggregate import render_markdown_table
        from letspi.planners.factory import BASELINE_PLANNERS, make_planner

        planners = [make_planner(name) for name in BASELINE_PLANNERS]
        eval_dir = out / "evaluation"
        with progress_bar() as bar:

            def factory(name: str, total: int):  # type: ignore[no-untyped-def]
                task = bar.add_task(f"evaluating {name}", total=total)
                return lambda k: bar.advance(task, k)

            results = evaluate(planners, batch, eval_dir, scenarios_file=str(scenarios_file),
                               progress_factory=factory)
    typer.echo(render_markdown_table({p.name: results[p.name] for p in planners}))
    from letspi.viz.report import write_report

    report = write_report(eval_dir)
    console.print(f"files: {highd_dir}/ (HighD CSV), {scenarios_file}, {eval_dir}/metrics.json, "
                  f"{eval_dir}/metrics.md, {eval_dir}/per_scenario/")
    console.print(f"report: {report}")
