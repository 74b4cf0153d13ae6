"""``letspi demo``: the main job on the embedded default (generated data)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from letspi.cli.common import console, progress_bar, user_errors
from letspi.registry.factory import DEFAULT_LLM


def demo(
    out: Annotated[Path, typer.Option(help="Working directory for all demo outputs.")] = Path("letspi-demo"),
    minutes: Annotated[float, typer.Option(help="Simulated minutes of traffic to generate.")] = 3.0,
    seed: int = 0,
    max_scenarios: Annotated[int, typer.Option(help="Scenarios to sample and evaluate.")] = 1000,
    llm: Annotated[str, typer.Option(help="Embedded (or any) model spec for both LetsPi phases.")] = DEFAULT_LLM,
    llm_collect: Annotated[int, typer.Option(help="Scenarios in the memory collection phase (0: skip LLMs).")] = 8,
    llm_eval: Annotated[int, typer.Option(help="Held-back scenarios for the LLM head-to-head table.")] = 8,
) -> None:
    """The main job: generate (or reuse) SUMO traffic as HighD files, extract planning scenarios,
    evaluate the baselines (human, cv, idm, sf, sf-opt) and print the paper-style table.

    Then LetsPi itself: the memory collection phase (physics-informed prompt, reflection) with the
    embedded model on ``llm_collect`` scenarios, and a head-to-head of baselines, letspi-memory
    and letspi-fast on ``llm_eval`` other scenarios (LLM calls take seconds each on 2 cores).

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
        from letspi.registry.factory import BASELINE_PLANNERS, make_planner

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
    llm_report = None
    if llm_collect > 0 and llm_eval > 0:
        llm_report = _llm_demo(batch, out, str(scenarios_file), llm, llm_collect, llm_eval)
    console.print(f"files: {highd_dir}/ (HighD CSV), {scenarios_file}, {eval_dir}/metrics.json, "
                  f"{eval_dir}/metrics.md, {eval_dir}/per_scenario/")
    console.print(f"report: {report}")
    if llm_report is not None:
        console.print(f"LetsPi report: {llm_report}")


def _llm_demo(batch, out: Path, scenarios_file: str, llm: str, n_collect: int, n_eval: int) -> Path:  # type: ignore[no-untyped-def]
    """Collect a small memory, then compare planners on disjoint held-back scenarios."""
    import numpy as np

    from letspi.core.memory import MemoryBank
    from letspi.core.phases import MemoryPhase, collect
    from letspi.evaluation.harness import evaluate
    from letspi.metrics.aggregate import render_markdown_table
    from letspi.registry.factory import PlannerOptions, make_planners
    from letspi.viz.report import write_report

    # spread both sets over the recording: every other scenario of the first 2 x n rows
    n = min(len(batch), 2 * (n_collect + n_eval))
    rows = np.arange(n)
    collect_rows, eval_rows = rows[0::2][:n_collect], rows[1::2][:n_eval]
    memory = out / "memory.sqlite"
    # the two sets as files, so ablations can run on exactly them (`letspi ablate --scenarios ...`)
    from letspi.scenario.store import save_scenarios

    save_scenarios(batch.take(collect_rows), out / "scenarios-llm-collect.arrow")
    save_scenarios(batch.take(eval_rows), out / "scenarios-llm-eval.arrow")
    with user_errors():
        options = PlannerOptions(llm=llm, fast_llm=llm, memory=memory)
        memory_planner, = make_planners(["letspi-memory"], options)
        phase: MemoryPhase = memory_planner.phase  # type: ignore[attr-defined]
        with MemoryBank.open(memory) as bank, progress_bar() as bar:
            task = bar.add_task(f"memory collection ({llm})", total=len(collect_rows))
            stats = collect(phase, batch.take(collect_rows), bank, progress=lambda k: bar.advance(task, k))
        console.print(f"memory: {stats.stored} new, {stats.skipped} reused, {stats.validated} validated -> {memory}")
        options = PlannerOptions(llm=llm, fast_llm=llm, memory=memory, memory_key=phase.config_key)
        planners = make_planners(["human", "idm", "sf", "sf-opt", "gnp"], options)
        planners += [memory_planner, *make_planners(["letspi-fast"], options)]
        eval_dir = out / "evaluation-llm"
        with progress_bar() as bar:

            def factory(name: str, total: int):  # type: ignore[no-untyped-def]
                task = bar.add_task(f"evaluating {name}", total=total)
                return lambda k: bar.advance(task, k)

            results = evaluate(planners, batch.take(eval_rows), eval_dir, scenarios_file=scenarios_file,
                               progress_factory=factory)
    typer.echo(f"\nLetsPi with {llm} on {len(eval_rows)} held-back scenarios (memory from {len(collect_rows)} others):")
    typer.echo(render_markdown_table({p.name: results[p.name] for p in planners}))
    return write_report(eval_dir)
