"""``letspi collect`` (memory collection), ``letspi plan`` (one scenario in full), ``letspi ablate`` and
``letspi prompt`` (the rendered prompt, no model call)."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.pretty import pprint

from letspi.assembly.build import Builder
from letspi.assembly.planner_table import planner_table
from letspi.assembly.planners import build_planners
from letspi.assembly.resolve import Resolver, goals_config
from letspi.cli.common import (
    ConcurrencyOpt,
    command_line,
    console,
    print_run,
    progress_bar,
    user_errors,
)
from letspi.cli.evaluate import load_limited, progress_factory
from letspi.cli.options import planner_options
from letspi.evaluation.ablations import ABLATION_KINDS, run_ablation
from letspi.evaluation.results import read_summary
from letspi.evaluation.summary import summary_markdown
from letspi.execution.ordered import RunnerConfig, ScenariosFailedError
from letspi.fsutil import writer_lock
from letspi.llm.describe import describe_scenario
from letspi.llm.prompts import render_fast_prompt, render_physics_prompt
from letspi.llm.spec import default_concurrency
from letspi.method.matching import TOP_K
from letspi.method.memory import MemoryBank
from letspi.method.phases import Retriever, memory_example, messages_text
from letspi.method.phases import collect as run_collect
from letspi.metrics.compute import compute_metrics
from letspi.planners.llm import LLM_CACHE, MEMORY_PHASE_OPTIONS, LetsPiFastPlanner, LetsPiMemoryPlanner
from letspi.planners.options import PlannerOptions
from letspi.scenario.identity import dataset_digest, scenario_digests
from letspi.scenario.store import load_scenarios


@planner_options(declared=MEMORY_PHASE_OPTIONS)
def collect(
    scenarios: Annotated[Path, typer.Option(help="Scenario file to collect experiences on.")],
    memory: Annotated[Path, typer.Option(help="Memory bank (SQLite; created if missing, resumed if present).")],
    options: PlannerOptions,
    limit: Annotated[int | None, typer.Option(help="Only the first N scenarios.")] = None,
    concurrency: ConcurrencyOpt = None,
) -> None:
    """Collect a memory bank of LLM experiences. Physics-informed prompt, reasoning and reflection; each
    experience is keyed by the scenario's content and the collection configuration's key (printed).
    Resumable: rerun the same command; stored experiences are skipped, fallbacks retried. --concurrency
    scenarios run at once, stored in scenario order, so the bank does not depend on it.
    """
    with user_errors(resumes=True) as tally, writer_lock(memory, command_line(), directory=False):
        batch = load_limited(scenarios, limit)
        digests = scenario_digests(batch)
        config = Resolver(options).memory_phase()
        tally.track(len(batch), lambda: _stored_memories(memory, config.key(), digests))
        runner = RunnerConfig(concurrency=default_concurrency(config.llm.spec) if concurrency is None else concurrency)
        phase, load_s = Builder(cache="default" if options.get(LLM_CACHE) else None).memory_phase(config)
        created = not memory.exists()
        with _removed_if_empty_on_failure(memory, created), MemoryBank.open(memory) as bank, progress_bar() as bar:
            bank.record_dataset(dataset_digest(digests), str(scenarios), len(batch))
            done = len(bank.done_digests(config.key()) & set(digests))
            task = bar.add_task("collecting", total=len(batch), completed=done)
            try:
                stats = run_collect(phase, batch, bank, runner=runner,
                                    progress=lambda st: bar.update(task, completed=done + st.done, run=st))
            except ScenariosFailedError as exc:
                print_run("collect", exc.stats)
                raise
            total = bank.count(validated_only=False, config_key=config.key())
            validated = bank.count(config_key=config.key())
    console.print(f"configuration {config.key()} ({config.llm.spec}; model loaded in {load_s:.1f} s)")
    if stats.run is not None:
        print_run("collect", stats.run)
    console.print(
        f"{stats.stored} new experiences: {stats.validated} validated, {stats.fallback_results} fell back "
        f"(stored flagged, never retrieved, retried on the next run), {stats.refinements} refinements, "
        f"{stats.fallback_replies} fallback replies; {stats.cached_calls}/{stats.calls} model calls from the cache; "
        f"{stats.skipped} already stored")
    console.print(f"bank {memory}: {total} experiences of this configuration, {validated} validated "
                  f"(use --memory-key {config.key()} to retrieve only these)")


def _stored_memories(memory: Path, config_key: str, digests: np.ndarray) -> int:
    """Scenarios of ``digests`` with a finished experience of ``config_key`` in the bank (0 without a bank)."""
    if not memory.exists():
        return 0
    with MemoryBank.open(memory, readonly=True) as bank:
        return len(bank.done_digests(config_key) & {str(d) for d in digests})


@contextmanager
def _removed_if_empty_on_failure(memory: Path, created: bool) -> Iterator[None]:
    """A bank this run created and that holds no experience when the run fails is removed (no
    partial output); a bank with experiences stays (rerun to resume)."""
    try:
        yield
    except BaseException:
        if created and memory.exists():
            with MemoryBank.open(memory, readonly=True) as bank:
                empty = bank.count(validated_only=False) == 0
            if empty:
                for p in (memory, memory.with_name(memory.name + "-wal"), memory.with_name(memory.name + "-shm")):
                    p.unlink(missing_ok=True)
        raise


def _round(v: Any) -> Any:
    if isinstance(v, float | np.floating):
        f = float(v)
        return round(f, 3) if np.isfinite(f) else str(f)
    if isinstance(v, np.integer | np.bool_):
        return v.item()
    return v


@planner_options()
def plan(
    scenarios: Annotated[Path, typer.Option(help="Scenario file.")],
    index: Annotated[int, typer.Option(help="Row of the scenario in the file.")],
    options: PlannerOptions,
    planner: Annotated[str, typer.Option(help="Planner KIND or LABEL=KIND (`letspi planners` lists them).")] = "llm",
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
    show_prompt: Annotated[bool, typer.Option(help="Include the prompt(s) sent to the LLM.")] = False,
) -> None:
    """Plan one scenario and show the details. Parameters, goal, trajectory summary, metrics, the LLM's
    rationale, reflection iterations and retrieved memories."""
    with user_errors():
        if index < 0:
            raise ValueError(f"--index must be >= 0, got {index}")
        batch = load_scenarios(scenarios, [index])
        built = build_planners([planner], options)[0]
        p = built.planner
        t0 = time.perf_counter()
        result = p.plan(batch if built.reads_future else batch.history())
        elapsed = time.perf_counter() - t0
    metrics = compute_metrics(batch, result.xy_m, result.vxy_mps, result.goals_xy_m).to_frame().iloc[0].to_dict()
    xy = result.xy_m[0]
    out: dict[str, Any] = {
        "scenario_id": str(batch.scenario_id[0]),
        "planner": built.name,
        "config_key": built.key,
        "inference_s": round(elapsed, 3),
        "model_load_s": round(built.load_s, 3),
        "goal_xy_m": [round(float(v), 2) for v in result.goals_xy_m[0]],
        "trajectory": {
            "end_xy_m": [round(float(v), 2) for v in xy[-1]],
            "mean_speed_mps": round(float(np.hypot(*result.vxy_mps[0].T).mean()), 2),
            "every_1s_xy_m": [[round(float(a), 2), round(float(b), 2)] for a, b in xy[24::25]],
        },
        "info": {k: _round(v[0]) for k, v in result.info.items() if np.ndim(v) == 1},
        "metrics": {k: _round(v) for k, v in metrics.items()},
        "rationale": None,
    }
    out.update(_llm_details(p, show_prompt))
    if as_json:
        typer.echo(json.dumps(out, indent=2))
    else:
        pprint(out, expand_all=True)


def _llm_details(p: object, show_prompt: bool) -> dict[str, Any]:
    """What an LLM planner's last call did: reflection iterations, retrieved memories, rationale (and
    the prompts with ``show_prompt``)."""
    details: dict[str, Any] = {}
    if isinstance(p, LetsPiMemoryPlanner):
        details["iterations"] = [
            {"iteration": it.iteration, "safe": it.safe, "rationale": it.proposal.rationale or None,
             "params": {k: round(v, 3) for k, v in it.proposal.params.as_dict().items()},
             "lon_factor": it.proposal.lon_factor, "lane_factor": it.proposal.lane_factor,
             "fallback": it.proposal.fallback, "safety_report": it.report.to_text(it.proposal),
             **({"prompt": it.proposal.prompt, "reply": it.proposal.reply} if show_prompt else {})}
            for it in p.last_iterations
        ]
        if p.last_iterations:
            final = p.last_iterations[-1].proposal
            details["rationale"] = final.rationale or ("(fallback: no valid model answer)" if final.fallback else None)
    if isinstance(p, LetsPiFastPlanner):
        details["retrieved_memories"] = [{"scenario_id": sid, "similarity": round(s, 4)} for sid, s in p.last_retrieved]
        if p.last_proposal is not None:
            details["rationale"] = p.last_proposal.rationale or None
            if show_prompt:
                details["prompt"] = p.last_proposal.prompt
                details["reply"] = p.last_proposal.reply
    return details


def _pairs(items: list[str] | None) -> list[tuple[str, str]]:
    out_pairs = []
    for item in items or []:
        mem, sep, fast = item.partition(",")
        if not sep or not mem or not fast:
            raise typer.BadParameter(f"--combo must be MEMORY_SPEC,FAST_SPEC, got {item!r}")
        out_pairs.append((mem.strip(), fast.strip()))
    return out_pairs


@planner_options(kinds=[kind.name for kind in planner_table().kinds if kind.uses_llm])
def ablate(
    kind: Annotated[str, typer.Argument(help="|".join(ABLATION_KINDS))],
    scenarios: Annotated[Path, typer.Option(help="Evaluation scenarios (held back from the memory).")],
    out: Annotated[Path, typer.Option(help="Evaluation directory; results go to OUT/ablations/KIND/.")],
    options: PlannerOptions,
    limit: Annotated[int | None, typer.Option(help="Only the first N evaluation scenarios.")] = None,
    collect_scenarios: Annotated[Path | None, typer.Option(help="llm-combinations: scenarios to collect on.")] = None,
    collect_limit: Annotated[int | None, typer.Option(help="llm-combinations: first N collection scenarios.")] = None,
    combo: Annotated[list[str] | None, typer.Option(help="llm-combinations: MEMORY_SPEC,FAST_SPEC (repeat).")] = None,
    concurrency: ConcurrencyOpt = None,
) -> None:
    """Run one of the paper's ablations and print its table. Also written to OUT/ablations/KIND/metrics.md."""
    with user_errors(resumes=True):
        batch = load_limited(scenarios, limit)
        collect_batch = load_limited(collect_scenarios, collect_limit) if collect_scenarios is not None else None
        with progress_bar() as bar:
            results = run_ablation(kind, batch, out, options, scenarios_file=str(scenarios),
                                   collect_batch=collect_batch, combinations=_pairs(combo),
                                   progress_factory=progress_factory(bar), concurrency=concurrency, on_run=print_run)
    typer.echo(summary_markdown(read_summary(out / "ablations" / kind), list(results)))


def prompt(
    scenarios: Annotated[Path, typer.Option(help="Scenario file.")],
    index: Annotated[int, typer.Option(help="Row of the scenario in the file.")],
    fast: Annotated[bool, typer.Option(help="The fast prompt (with memories from --memory) instead.")] = False,
    memory: Annotated[Path | None, typer.Option(help="Memory bank for the fast prompt's examples.")] = None,
    top_k: Annotated[int, typer.Option(help="Memories retrieved for the fast prompt.")] = TOP_K,
    goals: Annotated[str, typer.Option(help="Goal source: learned, kinematic or oracle.")] = "learned",
) -> None:
    """Print the rendered prompt for one scenario. No model is called: the physics-informed prompt of the
    memory-collection phase, or with --fast the short prompt of the fast-inference phase."""
    with user_errors():
        batch = load_scenarios(scenarios, [index])
        builder = Builder(cache=None)
        goal = builder.goal_predictor(goals_config(goals)).predict_goals(batch.history()).top[0]
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
