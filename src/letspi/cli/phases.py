"""``letspi collect`` (memory collection phase) and ``letspi plan`` (one scenario, shown in full)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer

from letspi.cli.common import console, progress_bar, user_errors
from letspi.registry.factory import DEFAULT_FAST_LLM, DEFAULT_LLM


def collect(
    scenarios: Annotated[Path, typer.Option(help="Scenario file to collect experiences on.")],
    memory: Annotated[Path, typer.Option(help="Memory bank (SQLite; created if missing, resumed if present).")],
    llm: Annotated[str, typer.Option(help="Model spec of the memory-collection phase.")] = DEFAULT_LLM,
    limit: Annotated[int | None, typer.Option(help="Only the first N scenarios.")] = None,
    max_iterations: Annotated[int, typer.Option(help="Reflection refinements per scenario.")] = 3,
    goals: Annotated[str, typer.Option(help="Goal source: learned, kinematic or oracle.")] = "learned",
    cache: Annotated[bool, typer.Option(help="Persistent LLM response cache.")] = True,
) -> None:
    """Memory collection: physics-informed prompt, reasoning, reflection; stores experiences.

    Resumable: rerun the same command after a crash; stored experiences are kept and skipped.
    """
    import numpy as np

    from letspi.core.memory import MemoryBank
    from letspi.core.phases import MemoryPhase
    from letspi.core.phases import collect as run_collect
    from letspi.core.thresholds import ReflectionThresholds
    from letspi.registry.factory import make_advisor, make_goal_predictor
    from letspi.planners.sf_params import load_sf_params
    from letspi.scenario.store import count_scenarios, load_scenarios

    with user_errors():
        n = count_scenarios(scenarios)
        batch = load_scenarios(scenarios, None if limit is None else np.arange(min(limit, n)))
        sf_params, _ = load_sf_params()
        phase = MemoryPhase(make_advisor(llm, cache), make_goal_predictor(goals),
                            sf_params.r_col_m, thresholds=ReflectionThresholds(max_iterations=max_iterations))
        with MemoryBank.open(memory) as bank, progress_bar() as bar:
            task = bar.add_task("collecting", total=len(batch))
            stats = run_collect(phase, batch, bank, progress=lambda k: bar.advance(task, k))
            total = bank.count(validated_only=False)
            validated = bank.count()
    console.print(
        f"{stats.stored} new experiences ({stats.validated} validated, {stats.refinements} refinements, "
        f"{stats.fallbacks} fallback replies), {stats.skipped} already stored; bank {memory}: "
        f"{total} experiences, {validated} validated"
    )


def _round(v: Any) -> Any:
    import numpy as np

    if isinstance(v, float | np.floating):
        f = float(v)
        return round(f, 3) if np.isfinite(f) else str(f)
    if isinstance(v, np.integer | np.bool_):
        return v.item()
    return v


def plan(
    scenarios: Annotated[Path, typer.Option(help="Scenario file.")],
    index: Annotated[int, typer.Option(help="Row of the scenario in the file.")],
    planner: Annotated[str, typer.Option(help="Planner name (llm, letspi-memory, letspi-fast, sf, ...).")] = "llm",
    llm: Annotated[str, typer.Option(help="Model spec of llm / letspi-memory.")] = DEFAULT_LLM,
    fast_llm: Annotated[str, typer.Option(help="Model spec of letspi-fast.")] = DEFAULT_FAST_LLM,
    memory: Annotated[Path | None, typer.Option(help="Memory bank for letspi-fast.")] = None,
    top_k: int = 3,
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
    show_prompt: Annotated[bool, typer.Option(help="Include the prompt(s) sent to the LLM.")] = False,
) -> None:
    """Plan one scenario and show parameters, goal, trajectory summary, metrics, the LLM's rationale,
    reflection iterations and retrieved memories."""
    import time

    import numpy as np

    from letspi.metrics.evaluate import compute_metrics
    from letspi.registry.factory import PlannerOptions, make_planner
    from letspi.planners.llm import LetsPiFastPlanner, LetsPiMemoryPlanner
    from letspi.scenario.store import load_scenarios

    with user_errors():
        batch = load_scenarios(scenarios, [index])
        p = make_planner(planner, PlannerOptions(llm=llm, fast_llm=fast_llm, memory=memory, top_k=top_k))
        t0 = time.perf_counter()
        result = p.plan(batch)
        elapsed = time.perf_counter() - t0
    metrics = compute_metrics(batch, result.xy_m, result.vxy_mps, result.goals_xy_m).to_frame().iloc[0].to_dict()
    xy = result.xy_m[0]
    out: dict[str, Any] = {
        "scenario_id": str(batch.scenario_id[0]),
        "planner": p.name,
        "inference_s": round(elapsed, 3),
        "goal_xy_m": [round(float(v), 2) for v in result.goals_xy_m[0]],
        "trajectory": {
            "end_xy_m": [round(float(v), 2) for v in xy[-1]],
            "mean_speed_mps": round(float(np.hypot(*result.vxy_mps[0].T).mean()), 2),
            "every_1s_xy_m": [[round(float(a), 2), round(float(b), 2)] for a, b in xy[24::25]],
        },
        "info": {k: _round(v[0]) for k, v in result.info.items()},
        "metrics": {k: _round(v) for k, v in metrics.items()},
    }
    if isinstance(p, LetsPiMemoryPlanner):
        out["iterations"] = [
            {"iteration": it.iteration, "safe": it.safe, "rationale": it.proposal.rationale,
             "params": {k: round(v, 3) for k, v in it.proposal.params.as_dict().items()},
             "lon_factor": it.proposal.lon_factor, "lane_factor": it.proposal.lane_factor,
             "fallback": it.proposal.fallback, "safety_report": it.report.to_text(it.proposal),
             **({"prompt": it.proposal.prompt, "reply": it.proposal.reply} if show_prompt else {})}
            for it in p.last_iterations
        ]
        out["rationale"] = p.last_iterations[-1].proposal.rationale if p.last_iterations else ""
    if isinstance(p, LetsPiFastPlanner):
        out["retrieved_memories"] = [{"scenario_id": sid, "similarity": round(s, 4)} for sid, s in p.last_retrieved]
        if p.last_proposal is not None:
            out["rationale"] = p.last_proposal.rationale
            if show_prompt:
                out["prompt"] = p.last_proposal.prompt
                out["reply"] = p.last_proposal.reply
    if as_json:
        typer.echo(json.dumps(out, indent=2))
    else:
        from rich.pretty import pprint

        pprint(out, expand_all=True)


def ablate(
    kind: Annotated[str, typer.Argument(help="reflection|goal-adjustment|few-shot|memory-size|llm-combinations")],
    scenarios: Annotated[Path, typer.Option(help="Evaluation scenarios (held back from the memory).")],
    out: Annotated[Path, typer.Option(help="Evaluation directory; results go to OUT/ablations/KIND/.")],
    memory: Annotated[Path | None, typer.Option(help="Memory bank (needed by the fast-phase ablations).")] = None,
    memory_key: Annotated[str | None, typer.Option(
        help="Only memories collected under this configuration key (default: all in the bank).")] = None,
    limit: Annotated[int | None, typer.Option(help="Only the first N evaluation scenarios.")] = None,
    llm: Annotated[str, typer.Option(help="Memory-phase model spec.")] = DEFAULT_LLM,
    fast_llm: Annotated[str, typer.Option(help="Fast-phase model spec.")] = DEFAULT_FAST_LLM,
    top_k: int = 3,
    collect_scenarios: Annotated[Path | None, typer.Option(help="llm-combinations: scenarios to collect on.")] = None,
    collect_limit: Annotated[int | None, typer.Option(help="llm-combinations: first N collection scenarios.")] = None,
    combo: Annotated[list[str] | None, typer.Option(help="llm-combinations: MEMORY_SPEC,FAST_SPEC (repeat).")] = None,
    cache: Annotated[bool, typer.Option(help="Persistent LLM response cache.")] = True,
) -> None:
    """Run one of the paper's ablations and print its table (also OUT/ablations/KIND/metrics.md)."""
    import numpy as np

    from letspi.evaluation.ablations import run_ablation
    from letspi.metrics.aggregate import render_markdown_table
    from letspi.registry.factory import PlannerOptions
    from letspi.scenario.store import count_scenarios, load_scenarios

    def pairs(items: list[str] | None) -> list[tuple[str, str]]:
        out_pairs = []
        for item in items or []:
            mem, sep, fast = item.partition(",")
            if not sep or not mem or not fast:
                raise typer.BadParameter(f"--combo must be MEMORY_SPEC,FAST_SPEC, got {item!r}")
            out_pairs.append((mem.strip(), fast.strip()))
        return out_pairs

    with user_errors():
        n = count_scenarios(scenarios)
        batch = load_scenarios(scenarios, None if limit is None else np.arange(min(limit, n)))
        collect_batch = None
        if collect_scenarios is not None:
            m = count_scenarios(collect_scenarios)
            collect_batch = load_scenarios(
                collect_scenarios, None if collect_limit is None else np.arange(min(collect_limit, m)))
        options = PlannerOptions(llm=llm, fast_llm=fast_llm, memory=memory, memory_key=memory_key, top_k=top_k,
                                 llm_cache=cache)
        with progress_bar() as bar:

            def factory(name: str, total: int):  # type: ignore[no-untyped-def]
                task = bar.add_task(name, total=total)
                return lambda k: bar.advance(task, k)

            results = run_ablation(kind, batch, out, options, scenarios_file=str(scenarios),
                                   collect_batch=collect_batch, combinations=pairs(combo), progress_factory=factory)
    typer.echo(render_markdown_table(results))


def prompt(
    scenarios: Annotated[Path, typer.Option(help="Scenario file.")],
    index: Annotated[int, typer.Option(help="Row of the scenario in the file.")],
    fast: Annotated[bool, typer.Option(help="The fast prompt (with memories from --memory) instead.")] = False,
    memory: Annotated[Path | None, typer.Option(help="Memory bank for the fast prompt's examples.")] = None,
    top_k: int = 3,
    goals: Annotated[str, typer.Option(help="Goal source: learned, kinematic or oracle.")] = "learned",
) -> None:
    """Print the rendered prompt for one scenario (calls no model): the physics-informed prompt of the
    memory-collection phase, or with --fast the short prompt of the fast-inference phase."""
    from letspi.core.memory import MemoryBank
    from letspi.core.phases import Retriever, memory_example, messages_text
    from letspi.llm.describe import describe_scenario
    from letspi.llm.prompts import render_fast_prompt, render_physics_prompt
    from letspi.registry.factory import make_goal_predictor
    from letspi.scenario.store import load_scenarios

    with user_errors():
        batch = load_scenarios(scenarios, [index])
        goal = make_goal_predictor(goals).predict_goals(batch).top[0]
        desc = describe_scenario(batch, goal)
        if not fast:
            messages = render_physics_prompt(desc)
        else:
            examples = []
            if memory is not None:
                with MemoryBank.open(memory, readonly=True) as bank:
                    examples = [memory_example(e) for e, _ in Retriever(bank, k=top_k).retrieve(batch)]
            messages = render_fast_prompt(desc, memories=examples)
    typer.echo(messages_text(messages))
