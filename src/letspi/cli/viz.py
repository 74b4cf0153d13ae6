"""``letspi plot`` (one scenario's diagrams) and ``letspi report`` (HTML report of an evaluation)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from letspi.cli.common import console, user_errors


def plot(
    scenarios: Annotated[Path, typer.Option(help="Scenario file (from `letspi data scenarios`).")],
    index: Annotated[int, typer.Option(help="Row of the scenario in the file (0-based).")],
    out: Annotated[Path, typer.Option(help="Output PNG file.")],
    planner: Annotated[list[str] | None, typer.Option(help="Planner to draw; repeat for several (default: sf).")]
    = None,
    iterations: Annotated[Path | None, typer.Option(
        help="JSON list of reflection iterations (IterationRecord fields) to show as text panels.")] = None,
    sf_params: Annotated[Path | None, typer.Option(help="Fitted SF parameters JSON (default: shipped).")] = None,
    neighbours: Annotated[str, typer.Option(help="Neighbour prediction for physics planners: idm|cv.")] = "idm",
) -> None:
    """Draw one scenario: trajectory diagram, time-space diagram with the gap to the preceding
    vehicle, and (with --iterations) the safety reports and LLM responses per reflection iteration."""
    from letspi.planners.factory import PlannerOptions, make_planner
    from letspi.scenario.store import load_scenarios
    from letspi.viz.figure import plot_scenario
    from letspi.viz.llm_panel import load_iterations

    with user_errors():
        if index < 0:
            raise ValueError(f"--index must be >= 0, got {index}")
        batch = load_scenarios(scenarios, [index])
        options = PlannerOptions(sf_params_file=sf_params, neighbour_mode=neighbours)
        names = list(planner) if planner else ["sf"]
        plans = {name: make_planner(name, options).plan(batch) for name in names}
        records = load_iterations(iterations) if iterations is not None else None
        plot_scenario(batch, 0, plans, records, out)
    console.print(f"scenario {batch.scenario_id[0]} -> {out}")


def report(
    directory: Annotated[Path, typer.Argument(help="Evaluation directory (from `letspi evaluate`).")],
    out: Annotated[Path | None, typer.Option(help="Output HTML file (default: DIR/report.html).")] = None,
    worst: Annotated[int, typer.Option(help="Worst scenarios shown per planner.")] = 3,
    diagrams: Annotated[bool, typer.Option(help="Re-plan and draw the worst scenarios.")] = True,
) -> None:
    """Write a self-contained HTML report of an evaluation directory (metrics table, distributions,
    worst scenarios with diagrams, ablation plots when DIR/ablations/ has them) and print its path."""
    from letspi.viz.report import write_report

    with user_errors():
        path = write_report(directory, out, n_worst=worst, with_diagrams=diagrams)
    typer.echo(str(path))
