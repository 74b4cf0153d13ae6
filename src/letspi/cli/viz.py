"""``letspi plot`` (one scenario's diagrams) and ``letspi report`` (HTML report of an evaluation)."""

from __future__ import annotations

from importlib.metadata import entry_points
from pathlib import Path
from typing import Annotated

import typer

from letspi.assembly.planners import build_planners
from letspi.cli.common import console, evaluation_mode, user_errors
from letspi.cli.options import planner_options
from letspi.evaluation.closed_loop import events_directory, scripted_for
from letspi.evaluation.results import planner_dir_name
from letspi.planners.llm import LetsPiMemoryPlanner
from letspi.planners.options import PlannerOptions
from letspi.scenario.store import load_scenarios
from letspi.simulation.config import ClosedLoopConfig, EvaluationMode
from letspi.viz.compare import write_comparison
from letspi.viz.figure import plot_scenario
from letspi.viz.llm_panel import load_iterations, panel_record
from letspi.viz.outcomes import simulate_panel
from letspi.viz.report import write_report


@planner_options()
def plot(
    scenarios: Annotated[Path, typer.Option(help="Scenario file (from `letspi data scenarios`).")],
    index: Annotated[int, typer.Option(help="Row of the scenario in the file (0-based).")],
    out: Annotated[Path, typer.Option(help="Output PNG file.")],
    options: PlannerOptions,
    planner: Annotated[list[str] | None, typer.Option(help="Planner KIND or LABEL=KIND to draw; repeat for "
                                                            "several (default: sf).")] = None,
    iterations: Annotated[Path | None, typer.Option(
        help="JSON list of reflection iterations (IterationRecord fields) to show as text panels.")] = None,
    mode: Annotated[EvaluationMode, typer.Option(
        parser=evaluation_mode, metavar="MODE",
        help="open-loop (default: the diagrams above) or closed-loop-log / -reactive / -hybrid (actors of "
             "scripted events from the scenario file's source directory, if it exists): simulate the "
             "scenario in SUMO and draw the closed-loop panel (open-loop plan above, every replan and the "
             "simulated paths below; one PNG per planner, OUT-LABEL.png when several).")] = EvaluationMode.OPEN_LOOP,
    replan_s: Annotated[float, typer.Option("--replan-s", help="Closed loop: replanning period [s].")] = 1.0,
) -> None:
    """Draw one scenario's diagrams. The trajectory diagram, the time-space diagram with the gap to the
    preceding vehicle, and the safety reports and LLM responses per reflection iteration (of a
    letspi-memory / llm planner, or from --iterations); with --mode closed-loop-*, the closed-loop panel."""
    with user_errors():
        if index < 0:
            raise ValueError(f"--index must be >= 0, got {index}")
        closed = ClosedLoopConfig(mode=mode, replan_s=replan_s) if mode.closed_loop else None
        batch = load_scenarios(scenarios, [index])
        built = build_planners(list(planner) if planner else ["sf"], options)
        if closed is not None:
            scripted = (scripted_for(batch, events_directory(scenarios), required=False).mask
                        if mode is EvaluationMode.HYBRID else None)
            for b in built:
                target = out if len(built) == 1 else out.with_name(f"{out.stem}-{planner_dir_name(b.name)}{out.suffix}")
                fig = simulate_panel(batch, b, closed, scripted_nbr=scripted)
                target.parent.mkdir(parents=True, exist_ok=True)
                fig.savefig(target, dpi=110)
                console.print(f"scenario {batch.scenario_id[0]}, {b.name}, {mode} -> {target}")
            return
        plans = {b.name: b.planner.plan(batch if b.reads_future else batch.history()) for b in built}
        records = load_iterations(iterations) if iterations is not None else None
        for b in built:
            p = b.planner
            if records is None and isinstance(p, LetsPiMemoryPlanner) and p.last_iterations:
                records = [panel_record(it) for it in p.last_iterations]
        plot_scenario(batch, 0, plans, records, out)
    console.print(f"scenario {batch.scenario_id[0]} -> {out}")


def report(
    directory: Annotated[Path, typer.Argument(help="Evaluation directory (from `letspi evaluate`).")],
    out: Annotated[Path | None, typer.Option(help="Output HTML file (default: DIR/report.html).")] = None,
    worst: Annotated[int, typer.Option(help="Worst scenarios shown per planner.")] = 3,
    diagrams: Annotated[bool, typer.Option(help="Draw the worst scenarios with their stored plans.")] = True,
) -> None:
    """Write a self-contained HTML report of an evaluation directory (metrics table, distributions, worst
    scenarios with diagrams of the stored plans, ablation plots when DIR/ablations/ has them), or of a highway-env
    directory (its table and one episode of each planner drawn with the plans it followed)."""
    with user_errors():
        path = _companion_report(directory, out) or write_report(directory, out, n_worst=worst, with_diagrams=diagrams)
    typer.echo(str(path))


#: the entry-point group through which other distributions write reports of their own results directories: each
#: entry point names a function ``(directory, out) -> Path | None`` (None: not its kind of directory)
REPORTS_GROUP = "letspi.reports"


def _companion_report(directory: Path, out: Path | None) -> Path | None:
    for ep in sorted(entry_points(group=REPORTS_GROUP), key=lambda e: e.name):
        written: Path | None = ep.load()(directory, out)
        if written is not None:
            return written
    return None


def compare(
    a: Annotated[Path, typer.Argument(help="Results directory A (e.g. open loop).")],
    b: Annotated[Path, typer.Argument(help="Results directory B of the same scenarios (e.g. closed loop).")],
    out: Annotated[Path | None, typer.Option(help="Output directory (default: B/compare).")] = None,
    examples: Annotated[int, typer.Option(help="Scenarios drawn per planner whose collision outcome differs.")] = 3,
    reference: Annotated[str | None, typer.Option(
        help="A planner label of A: compare every planner of B with it (same evaluation mode required). "
             "Default: each planner with the planner of the same label.")] = None,
) -> None:
    """Compare two evaluations on the scenarios both hold. For example open loop against closed loop, or
    your planner against sf with --reference: per planner and metric, A and B with 95 % intervals, the
    paired difference with its interval, and for rates the windows only A / only B fail with the exact
    McNemar p (compare.md, compare.json), and compare.html with panels of the scenarios whose outcome
    differs. Refused when the metrics configurations differ."""
    with user_errors():
        target = out if out is not None else Path(b) / "compare"
        cmp = write_comparison(a, b, target, n_examples=examples, reference=reference)
    typer.echo(cmp.markdown())
    console.print(f"comparison in {target}/ (compare.md, compare.json, compare.html)")
