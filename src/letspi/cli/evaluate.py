"""``letspi evaluate``: run planners on scenarios and write the paper-style table."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.progress import Progress

from letspi.cli.common import (
    ConcurrencyOpt,
    RequestTimeoutOpt,
    ShieldOpt,
    console,
    print_run,
    progress_bar,
    run_progress,
    user_errors,
)
from letspi.evaluation.harness import Progress as Progress_
from letspi.evaluation.harness import ProgressFactory
from letspi.evaluation.harness import evaluate as run_evaluation
from letspi.metrics.aggregate import render_markdown_table
from letspi.registry.build import build_planners
from letspi.registry.resolve import DEFAULT_FAST_LLM, DEFAULT_LLM, PlannerOptions
from letspi.scenario.store import count_scenarios, load_scenarios
from letspi.scenario.types import ScenarioBatch

PlannerOpt = Annotated[list[str], typer.Option(
    help="Planner KIND (human, cv, idm, sf, sf-opt, gnp, llm, letspi-memory, letspi-fast, letspi-fs) or "
         "LABEL=KIND for a second configuration of one kind; repeat for several.")]


def load_limited(scenarios: Path, limit: int | None) -> ScenarioBatch:
    """The first ``limit`` scenarios of a file (all when None)."""
    n_total = count_scenarios(scenarios)
    return load_scenarios(scenarios, None if limit is None else np.arange(min(limit, n_total)))


def progress_factory(bar: Progress) -> ProgressFactory:
    def factory(name: str, total: int) -> Progress_:
        return run_progress(bar, bar.add_task(name, total=total))

    return factory


def evaluate(
    scenarios: Annotated[Path, typer.Option(help="Scenario file (from `letspi data scenarios`).")],
    planner: PlannerOpt,
    out: Annotated[Path, typer.Option(help="Output directory (rerunning resumes; another dataset, metrics "
                                           "configuration or planner configuration is refused).")],
    limit: Annotated[int | None, typer.Option(help="Only the first N scenarios.")] = None,
    sf_params: Annotated[Path | None, typer.Option(help="Fitted SF parameters JSON (default: shipped).")] = None,
    neighbours: Annotated[
        str,
        typer.Option(help="Neighbour prediction of idm/sf/sf-opt/gnp/LLM planners: idm, constant_velocity, or "
                          "ground_truth_oracle (leaks the future: an upper bound, not a planner)."),
    ] = "idm",
    goals: Annotated[
        str, typer.Option(help="Goal source: learned (shipped transformer, or $LETSPI_GOAL_WEIGHTS), kinematic, or "
                               "oracle (true endpoint: leaks the future).")
    ] = "learned",
    llm: Annotated[str, typer.Option(help="Model of llm / letspi-memory (spec, e.g. llamacpp:smollm2-135m, "
                                          "ollama:llama3.1:8b, openai:MODEL@http://host:port/v1).")] = DEFAULT_LLM,
    fast_llm: Annotated[str, typer.Option(help="Model of letspi-fast / letspi-fs.")] = DEFAULT_FAST_LLM,
    memory: Annotated[Path | None, typer.Option(help="Memory bank (from `letspi collect`) for letspi-fast/fs.")] = None,
    top_k: Annotated[int, typer.Option(help="Memories retrieved per scenario by letspi-fast.")] = 3,
    memory_key: Annotated[str | None, typer.Option(
        help="Only memories collected under this configuration key (default: all in the bank).")] = None,
    allow_same_vehicle: Annotated[bool, typer.Option(
        help="Let retrieval return memories of the query's own vehicle or overlapping windows (a leak).")] = False,
    max_iterations: Annotated[int, typer.Option(help="Reflection refinements of letspi-memory (0: none).")] = 3,
    goal_adjustment: Annotated[bool, typer.Option(help="Let the LLM adjust goals (off: 'w/o GA' ablation).")] = True,
    cache: Annotated[bool, typer.Option(help="Persistent LLM response cache (cached rows are excluded from the "
                                             "inference time).")] = True,
    concurrency: ConcurrencyOpt = None,
    request_timeout: RequestTimeoutOpt = 120.0,
    shield: ShieldOpt = True,
    mlp_weights: Annotated[Path | None, typer.Option(
        help="Weights of the mlp regressor (from `letspi train mlp`; default: $LETSPI_MLP_WEIGHTS).")] = None,
) -> None:
    """Evaluate planners: DIR/metrics.json, DIR/metrics.md and per-scenario Parquet parts with the plans."""
    with user_errors():
        batch = load_limited(scenarios, limit)
        options = PlannerOptions(sf_params_file=sf_params, neighbour_mode=neighbours, goals=goals, llm=llm,
                                 fast_llm=fast_llm, memory=memory, memory_key=memory_key, top_k=top_k,
                                 max_iterations=max_iterations, goal_adjustment=goal_adjustment, llm_cache=cache,
                                 allow_same_vehicle=allow_same_vehicle, llm_timeout_s=request_timeout,
                                 shield=shield, mlp_weights=mlp_weights)
        planners = build_planners(planner, options)
        with progress_bar() as bar:
            results = run_evaluation(planners, batch, out, scenarios_file=str(scenarios),
                                     progress_factory=progress_factory(bar), concurrency=concurrency, on_run=print_run)
    typer.echo(render_markdown_table({p.name: results[p.name] for p in planners}))
    console.print(f"results in {out}/ (metrics.json, metrics.md, per_scenario/; keys in run.json and "
                  "per_scenario/*/config.json)")
