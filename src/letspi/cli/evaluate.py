"""``letspi evaluate``: run planners on scenarios and write the paper-style table."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from letspi.cli.common import console, progress_bar, user_errors
from letspi.registry.factory import DEFAULT_FAST_LLM, DEFAULT_LLM


def evaluate(
    scenarios: Annotated[Path, typer.Option(help="Scenario file (from `letspi data scenarios`).")],
    planner: Annotated[list[str], typer.Option(help="Planner name; repeat for several.")],
    out: Annotated[Path, typer.Option(help="Output directory (rerunning resumes).")],
    limit: Annotated[int | None, typer.Option(help="Only the first N scenarios.")] = None,
    sf_params: Annotated[Path | None, typer.Option(help="Fitted SF parameters JSON (default: shipped).")] = None,
    neighbours: Annotated[
        str,
        typer.Option(help="Neighbour prediction of idm/sf/sf-opt: idm, constant_velocity, or ground_truth_oracle "
                          "(leaks the future: an upper bound, not a planner)."),
    ] = "idm",
    goals: Annotated[
        str, typer.Option(help="Goal source of sf/sf-opt: learned (shipped transformer), kinematic, or oracle "
                               "(true endpoint: leaks the future).")
    ] = "learned",
    llm: Annotated[str, typer.Option(help="Model of llm / letspi-memory (spec, e.g. llamacpp:smollm2-135m, "
                                          "ollama:llama3.1:8b, openai:MODEL@http://host:port/v1).")] = DEFAULT_LLM,
    fast_llm: Annotated[str, typer.Option(help="Model of letspi-fast / letspi-fs.")] = DEFAULT_FAST_LLM,
    memory: Annotated[Path | None, typer.Option(help="Memory bank (from `letspi collect`) for letspi-fast/fs.")] = None,
    top_k: Annotated[int, typer.Option(help="Memories retrieved per scenario by letspi-fast.")] = 3,
    memory_key: Annotated[str | None, typer.Option(
        help="Only memories collected under this configuration key (default: all in the bank).")] = None,
    max_iterations: Annotated[int, typer.Option(help="Reflection refinements of letspi-memory (0: none).")] = 3,
    goal_adjustment: Annotated[bool, typer.Option(help="Let the LLM adjust goals (off: 'w/o GA' ablation).")] = True,
    cache: Annotated[bool, typer.Option(help="Persistent LLM response cache.")] = True,
) -> None:
    """Evaluate planners: DIR/metrics.json, DIR/metrics.md and per-scenario Parquet parts."""
    import numpy as np

    from letspi.evaluation.harness import evaluate as run_evaluation
    from letspi.registry.factory import PlannerOptions, make_planners
    from letspi.scenario.store import count_scenarios, load_scenarios

    with user_errors():
        n_total = count_scenarios(scenarios)
        indices = None if limit is None else np.arange(min(limit, n_total))
        batch = load_scenarios(scenarios, indices)
        options = PlannerOptions(sf_params_file=sf_params, neighbour_mode=neighbours, goals=goals, llm=llm,
                                 fast_llm=fast_llm, memory=memory, memory_key=memory_key, top_k=top_k,
                                 max_iterations=max_iterations,
                                 goal_adjustment=goal_adjustment, llm_cache=cache)
        planners = make_planners(planner, options)
        with progress_bar() as bar:

            def factory(name: str, total: int):  # type: ignore[no-untyped-def]
                task = bar.add_task(name, total=total)
                return lambda k: bar.advance(task, k)

            results = run_evaluation(
                planners, batch, out, scenarios_file=str(scenarios), progress_factory=factory
            )
    from letspi.metrics.aggregate import render_markdown_table

    typer.echo(render_markdown_table({p.name: results[p.name] for p in planners}))
    console.print(f"results in {out}/ (metrics.json, metrics.md, per_scenario/)")
