"""``letspi demo``: the main job on the embedded default (generated data, embedded model)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from letspi.assembly.build import Builder
from letspi.assembly.planner_table import DemoTable, planner_table
from letspi.assembly.planners import BuiltPlanner, build_planners
from letspi.assembly.resolve import Resolver
from letspi.cli.common import console, progress_bar, user_errors
from letspi.cli.evaluate import progress_factory
from letspi.cli.options import planner_options
from letspi.evaluation.harness import EvaluationSettings, evaluate
from letspi.evaluation.results import read_summary
from letspi.evaluation.summary import summary_markdown
from letspi.highd.io import list_recording_ids, read_recordings
from letspi.method.memory import MemoryBank
from letspi.method.phases import collect
from letspi.planners.llm import DEFAULT_LLM, LLM
from letspi.planners.options import PlannerOptions
from letspi.planners.sf_check import DecisionPlanner
from letspi.scenario.extract import count_windows, extract_scenarios
from letspi.scenario.identity import dataset_digest, scenario_digests
from letspi.scenario.split import split_by_vehicle
from letspi.scenario.store import save_scenarios
from letspi.scenario.types import ScenarioBatch
from letspi.trafficgen.generate import generate_highd
from letspi.viz.report import write_report

#: the kinds of the demo's two tables (``demo`` in the planner table)
BASELINES = planner_table().demo(DemoTable.BASELINES)
HEAD_TO_HEAD = planner_table().demo(DemoTable.HEAD_TO_HEAD)


@planner_options(kinds=sorted(set(BASELINES) | set(HEAD_TO_HEAD)),
                 exclude=("llm", "fast_llm", "memory", "memory_key", "llm_cache"))
def demo(
    options: PlannerOptions,
    out: Annotated[Path, typer.Option(help="Working directory for all demo outputs.")] = Path("letspi-demo"),
    minutes: Annotated[float, typer.Option(help="Simulated minutes of traffic to generate.")] = 3.0,
    seed: int = 0,
    max_scenarios: Annotated[int, typer.Option(help="Scenarios to sample and evaluate.")] = 1000,
    llm: Annotated[str, typer.Option(
        help="Embedded (or any) model spec for both LetsPi phases.")] = DEFAULT_LLM,
    llm_collect: Annotated[int, typer.Option(help="Scenarios in the memory collection phase (0: skip LLMs).")] = 8,
    llm_eval: Annotated[int, typer.Option(help="Held-back scenarios for the LLM head-to-head table.")] = 8,
) -> None:
    """The main job on generated traffic and the embedded model. Generates (or reuses) SUMO traffic as
    HighD files, extracts planning scenarios, evaluates the baselines (human, cv, idm, sf, sf-opt, gnp) and
    prints the paper-style table; then collects a memory with the embedded model on --llm-collect
    scenarios and compares the baselines, letspi-memory and letspi-fast on --llm-eval scenarios of other
    ego vehicles (LLM calls take seconds each). The default seed 0 keeps the scenarios out of the shipped
    sf parameters' fit (seed 1). Rerunning reuses finished work.
    """
    highd_dir = out / "highd"
    scenarios_file = out / "scenarios.arrow"
    eval_dir = out / "evaluation"
    with user_errors(resumes=True):
        if highd_dir.exists() and list_recording_ids(highd_dir):
            console.print(f"reusing recordings in {highd_dir}")
        else:
            with progress_bar() as bar:
                task = bar.add_task("simulating (SUMO)", total=100.0)
                generate_highd(highd_dir, minutes=minutes, seed=seed,
                               progress=lambda f: bar.update(task, completed=100.0 * f))
        recs = read_recordings(highd_dir)
        with progress_bar() as bar:
            task = bar.add_task("extracting scenarios", total=min(max_scenarios, count_windows(recs)))
            batch = extract_scenarios(recs, max_scenarios=max_scenarios, seed=seed,
                                      progress=lambda k: bar.advance(task, k))
        save_scenarios(batch, scenarios_file, extra_meta={"provenance": {"source": str(highd_dir), "seed": seed}})
        console.print(f"[green]{len(batch)} scenarios[/green] from {len(recs)} recording(s) -> {scenarios_file}")
        planners = build_planners(list(BASELINES), options)
        with progress_bar() as bar:
            evaluate(planners, batch, eval_dir, EvaluationSettings(scenarios_file=str(scenarios_file),
                                                                   progress_factory=progress_factory(bar)))
        typer.echo(summary_markdown(read_summary(eval_dir), [p.name for p in planners]))
        report = write_report(eval_dir)
        outputs = [f"{highd_dir}/ (HighD CSV)", str(scenarios_file), f"{eval_dir}/metrics.json, metrics.md, "
                   "per_scenario/ (with the plans)", str(report)]
        if llm_collect > 0 and llm_eval > 0:
            outputs += _llm_demo(batch, out, options.replace(llm=llm, fast_llm=llm), llm_collect, llm_eval)
    console.print("files:\n  " + "\n  ".join(outputs))


def _scenes_that_call_for_a_decision(batch: ScenarioBatch, rows: np.ndarray, n: int, options: PlannerOptions,
                                     rng: np.random.Generator) -> np.ndarray:
    """``n`` of ``rows``: half the riskiest by the decision step's risk model (scenes where a planner should
    not simply keep its defaults), half drawn at random from the others; sorted."""
    sf = build_planners(["sf-check"], options.replace(llm_cache=False))[0].planner
    assert isinstance(sf, DecisionPlanner)
    hist = batch.take(rows).history()
    risk = sf.choose(hist, sf.context(hist))[1].risk
    riskiest = rows[np.argsort(-risk, kind="stable")[: n // 2]]
    others = np.setdiff1d(rows, riskiest)
    return np.sort(np.concatenate([riskiest, rng.choice(others, min(n - len(riskiest), len(others)), replace=False)]))


def _llm_demo(batch: ScenarioBatch, out: Path, options: PlannerOptions, n_collect: int, n_eval: int) -> list[str]:
    """Collect a small memory on some ego vehicles, compare planners on other vehicles' scenarios (half of
    them the riskiest of those vehicles' windows, half at random)."""
    collect_rows, held_back = split_by_vehicle(batch, 0.5, seed=0)
    rng = np.random.default_rng(0)
    collect_rows = np.sort(rng.choice(collect_rows, min(n_collect, len(collect_rows)), replace=False))
    eval_rows = _scenes_that_call_for_a_decision(batch, held_back, min(n_eval, len(held_back)), options, rng)
    collect_file, eval_file = out / "scenarios-llm-collect.arrow", out / "scenarios-llm-eval.arrow"
    save_scenarios(batch.take(collect_rows), collect_file)  # `letspi ablate --scenarios` can reuse both sets
    save_scenarios(batch.take(eval_rows), eval_file)
    memory = out / "memory.sqlite"
    builder = Builder()
    options = options.replace(memory=memory)
    llm = options.get(LLM)
    phase_config = Resolver(options).memory_phase()
    phase, _ = builder.memory_phase(phase_config)
    to_collect = batch.take(collect_rows)
    with MemoryBank.open(memory) as bank, progress_bar() as bar:
        bank.record_dataset(dataset_digest(scenario_digests(to_collect)), str(collect_file), len(to_collect))
        task = bar.add_task(f"memory collection ({llm})", total=len(collect_rows))
        stats = collect(phase, to_collect, bank, progress=lambda st: bar.update(task, completed=st.done, run=st))
    console.print(f"memory: {stats.stored} new ({stats.validated} validated, {stats.fallback_results} fell back), "
                  f"{stats.skipped} reused -> {memory} (configuration {phase_config.key()})")
    # no response cache in the head-to-head: the fast phase's prompt can equal the memory phase's
    # first one, and a cache hit would hide the fast phase's latency (LLM planners are timed uncached)
    options = options.replace(memory_key=phase_config.key(), llm_cache=False)
    planners: list[BuiltPlanner] = build_planners(list(HEAD_TO_HEAD), options, builder=builder)
    eval_dir = out / "evaluation-llm"
    with progress_bar() as bar:
        evaluate(planners, batch.take(eval_rows), eval_dir,
                 EvaluationSettings(scenarios_file=str(eval_file), progress_factory=progress_factory(bar)))
    typer.echo(f"\nLetsPi with {llm} on {len(eval_rows)} scenarios of held-back ego vehicles "
               f"(memory from {len(collect_rows)} scenarios of other vehicles):")
    typer.echo(summary_markdown(read_summary(eval_dir), [p.name for p in planners]))
    report = write_report(eval_dir)
    return [str(memory), str(collect_file), str(eval_file), f"{eval_dir}/metrics.json, metrics.md, per_scenario/",
            str(report)]
