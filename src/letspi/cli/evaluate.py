"""``letspi evaluate``: run planners on scenarios and write the paper-style table."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.progress import Progress

from letspi.assembly.planner_table import planner_table
from letspi.assembly.planners import BuiltPlanner, build_planners, planner_kinds
from letspi.cli.common import (
    CONCURRENCY_HELP,
    LineProgress,
    command_line,
    console,
    evaluation_mode,
    print_run,
    progress_bar,
    run_progress,
    user_errors,
)
from letspi.cli.options import planner_options, setting_options
from letspi.evaluation.closed_loop import (
    ScriptedNeighbours,
    evaluate_closed_loop,
    events_directory,
    scripted_for,
)
from letspi.evaluation.harness import EvaluationSettings, ProgressFactory
from letspi.evaluation.harness import evaluate as run_evaluation
from letspi.evaluation.results import ProgressCallback, read_summary, reuse_line, reused_windows, stored_rows
from letspi.evaluation.summary import summary_markdown
from letspi.fsutil import writer_lock
from letspi.metrics.aggregate import AggValue
from letspi.planners.options import LLM_PANEL, PLANNERS_PANEL, PlannerOptions
from letspi.scenario.store import count_scenarios, load_scenarios
from letspi.scenario.types import ScenarioBatch
from letspi.simulation.config import ClosedLoopConfig, EvaluationMode
from letspi.simulation.settings import CLOSED_LOOP_OPTIONS, closed_loop_config

DATA, PLANNERS, LLM, CLOSED_LOOP, OUTPUT = "Data", PLANNERS_PANEL, LLM_PANEL, "Closed loop", "Output"
PlannerOpt = Annotated[list[str], typer.Option(help=planner_table().planner_help(), metavar="KIND",
                                               rich_help_panel=PLANNERS)]


def load_limited(scenarios: Path, limit: int | None) -> ScenarioBatch:
    """The first ``limit`` scenarios of a file (all when None)."""
    n_total = count_scenarios(scenarios)
    return load_scenarios(scenarios, None if limit is None else np.arange(min(limit, n_total)))


ModeOpt = Annotated[EvaluationMode, typer.Option(
    parser=evaluation_mode, metavar="MODE",
    help="open-loop (the paper's protocol: one plan at t = 0, neighbours replay the log), closed-loop-log (the "
         "ego follows its plan in SUMO and replans every --replan-s; neighbours replay the log), "
         "closed-loop-reactive (every neighbour is driven by SUMO's IDM from t = 0 and reacts to the ego; the "
         "recorded hard brakes and cut-ins are lost) or closed-loop-hybrid (neighbours replay the log while "
         "ahead of the ego and are handed to SUMO's IDM, capped at their recorded speed, once behind it in a lane "
         "its box covers; actors of scripted events, see --events, replay the log throughout).",
    rich_help_panel=CLOSED_LOOP)]
EventsOpt = Annotated[str | None, typer.Option(
    "--events", help="closed-loop-hybrid: HighD directory with the NN_events.csv of the scenarios' recordings "
                     "(their actors keep the log), or 'none'. Default: the directory the scenario file was cut "
                     "from (its provenance), if it still exists.", rich_help_panel=CLOSED_LOOP)]


ReferenceOpt = Annotated[str | None, typer.Option(
    help="Planner label every other planner of the directory is compared with, on the same windows (metrics.json "
         "\"paired\", metrics.md): differences with 95 % intervals, windows only one of them fails, exact McNemar "
         "p. Default: sf when the directory has it, else the first --planner.", rich_help_panel=OUTPUT)]
OutDirOpt = Annotated[Path, typer.Option(help="Output directory (rerunning resumes; another dataset, metrics "
                                                "configuration or planner configuration is refused).",
    rich_help_panel=OUTPUT)]
def closed_loop_line(closed: ClosedLoopConfig, planners: list[BuiltPlanner]) -> str:
    """The mode, each planner's replanning period and, with LLM planners, when they ask their model."""
    simulator = "SUMO" if closed.uses_sumo else "log replay"
    periods = ", ".join(f"{closed.replan_s_of(p.name):g} s ({p.name})" for p in planners)
    line = f"Mode: {closed.mode.value} ({simulator}), replanning every {periods}"
    if any(p.dual_rate for p in planners):
        dual = closed.dual_rate
        line += (f"; LLM planners ask their model every {dual.llm_period_s:g} s, answers in force after "
                 + ("the measured latency" if dual.measured else f"{dual.llm_latency_s:g} s"))
    return line


def scripted_neighbours_of(mode: EvaluationMode, events: str | None, scenarios: Path,
                           batch: ScenarioBatch) -> ScriptedNeighbours | None:
    """closed-loop-hybrid: the scripted neighbours (``--events`` DIR, ``none``, or the scenario file's source
    directory); None in the other modes, where ``--events`` is refused."""
    if mode is not EvaluationMode.HYBRID:
        if events is not None:
            raise ValueError(f"--events applies to --mode closed-loop-hybrid only, not {mode}")
        return None
    if events == "none":
        return scripted_for(batch, None)
    if events is not None:
        return scripted_for(batch, Path(events))
    return scripted_for(batch, events_directory(scenarios), required=False)


def progress_factory(bar: Progress | LineProgress) -> ProgressFactory:
    def factory(name: str, total: int) -> ProgressCallback:
        return run_progress(bar, bar.add_task(name, total=total))

    return factory


def _run_planners(planners: list[BuiltPlanner], batch: ScenarioBatch, out: Path, closed: ClosedLoopConfig | None,
                  scenarios: Path, scripted: ScriptedNeighbours | None,
                  concurrency: int | None, reference: str | None = None) -> dict[str, dict[str, AggValue]]:
    """Open or closed loop, with progress bars: the results per planner name."""
    with progress_bar() as bar:
        if closed is not None:
            return evaluate_closed_loop(planners, batch, out, closed, scenarios_file=str(scenarios),
                                        progress_factory=progress_factory(bar),
                                        scripted_nbr=None if scripted is None else scripted.mask, reference=reference)
        return run_evaluation(planners, batch, out, EvaluationSettings(
            scenarios_file=str(scenarios), progress_factory=progress_factory(bar), concurrency=concurrency,
            on_run=print_run, reference=reference))


@planner_options()
@setting_options(CLOSED_LOOP_OPTIONS, "closed_loop")
def evaluate(
    scenarios: Annotated[Path, typer.Option(help="Scenario file (from `letspi data scenarios`).",
    rich_help_panel=DATA)],
    planner: PlannerOpt,
    out: OutDirOpt,
    options: PlannerOptions,
    closed_loop: dict[str, Any],
    limit: Annotated[int | None, typer.Option(help="Only the first N scenarios.", rich_help_panel=DATA)] = None,
    concurrency: Annotated[int | None, typer.Option(help=CONCURRENCY_HELP, rich_help_panel=LLM)] = None,
    mode: ModeOpt = EvaluationMode.OPEN_LOOP,
    events: EventsOpt = None,
    reference: ReferenceOpt = None,
) -> None:
    """Evaluate planners on scenarios. Writes DIR/metrics.json, DIR/metrics.md and per-scenario Parquet
    parts with the plans (open loop, or closed loop with --mode)."""
    with user_errors(resumes=True) as tally, writer_lock(out, command_line()):
        labels = [label for label, _ in planner_kinds(planner)]
        closed = closed_loop_config(mode, closed_loop, labels, concurrency)
        batch = load_limited(scenarios, limit)
        tally.track(len(labels) * len(batch), lambda: min(stored_rows(out, labels), len(labels) * len(batch)))
        scripted = scripted_neighbours_of(mode, events, scenarios, batch)
        if scripted is not None:
            console.print(scripted.describe())
        planners = build_planners(planner, options)
        reused = reused_windows(out, labels, batch)
        _run_planners(planners, batch, out, closed, scenarios, scripted, concurrency, reference)
    resumed = reuse_line(reused, len(batch))
    if resumed:
        console.print(resumed, highlight=False)
    if closed is not None:
        typer.echo(closed_loop_line(closed, planners) + "\n")
    typer.echo(summary_markdown(read_summary(out), [p.name for p in planners]))
    console.print(f"results in {out}/ (metrics.json, metrics.md, per_scenario/; keys in run.json and "
                  "per_scenario/*/config.json)")
