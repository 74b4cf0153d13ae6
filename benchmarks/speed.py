"""``python -m benchmarks.speed``: benchmarks that print measured numbers (and ratios to a reference run)."""

from __future__ import annotations

import contextlib
import io
import json
import re
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.pretty import pprint
from rich.table import Table

from benchmarks.closed_loop import bench_closed_loop, bench_scenarios
from benchmarks.data import bench_data
from benchmarks.interrupt import MODES as INTERRUPT_MODES
from benchmarks.interrupt import bench_interrupt
from benchmarks.kernels import KERNELS, bench_kernels
from benchmarks.llm_concurrency import bench_concurrency
from benchmarks.llm_format import bench_formats
from benchmarks.llm_runtime import CONFIGS, bench_runtime
from benchmarks.metrics import bench_metrics
from benchmarks.physics import bench_frenet, bench_rollout
from benchmarks.realtime import bench_real_time
from benchmarks.retrieval import bench_phases, bench_retrieval
from benchmarks.robustness import PLAIN_PLANNERS, bench_robustness
from letspi.assembly.planner_table import planner_table
from letspi.cli.common import console, user_errors
from letspi.cli.options import planner_options
from letspi.llm.latency import bench_models
from letspi.planners.llm import DEFAULT_FAST_LLM, DEFAULT_LLM
from letspi.planners.options import PlannerOptions
from letspi.simulation.config import ClosedLoopConfig, EvaluationMode
from letspi.simulation.schedule import DEFAULT_LLM_PERIOD_S, DualRateConfig

app = typer.Typer(help="letspi's self-benchmarks: measured speed (and robustness, Ctrl-C) numbers, with ratios "
                       "to a reference run.", no_args_is_help=True, rich_markup_mode=None)

JsonOpt = Annotated[bool, typer.Option("--json", help="Machine-readable output.")]


def format_number(value: object) -> str:
    """One format for every number: thousands separators, counts without decimals (also counts held as
    floats), 3 significant decimals, an exponent only below 0.001."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return str(value)
    if isinstance(value, int) or float(value).is_integer():
        return f"{value:,.0f}"
    v = float(value)
    if abs(v) >= 100:
        return f"{v:,.1f}"
    if abs(v) >= 1:
        return f"{v:,.3f}"
    return f"{v:.3g}" if v != 0 else "0"


def _emit(result: dict[str, float], as_json: bool, title: str) -> None:
    if as_json:
        typer.echo(json.dumps(result, indent=2))
        return
    table = Table(title=title)
    table.add_column("measure")
    table.add_column("value", justify="right")
    for k, v in result.items():
        table.add_row(k, format_number(v))
    Console().print(table)


@app.command("data")
def data_cmd(
    minutes: Annotated[float, typer.Option(help="Simulated minutes to generate.")] = 10.0,
    seed: int = 0,
    n_load: Annotated[int, typer.Option(help="Scenarios in the load test.")] = 10_000,
    as_json: JsonOpt = False,
) -> None:
    """Generation time, extraction scenarios/s for one recording, load time of 10,000 scenarios."""
    _emit(bench_data(minutes=minutes, seed=seed, n_load=n_load), as_json, "speed data")


@app.command("physics")
def physics_cmd(
    n: Annotated[int, typer.Option(help="Scenarios (x 8 neighbours x 125 steps; 0: skip rollout, metrics).")] = 10_000,
    n_reference: Annotated[int, typer.Option(help="Scenarios run through the plain Python loops.")] = 100,
    frenet_n: Annotated[int, typer.Option(help="Scenarios of the batched frenet planner timing (0: skip).")] = 1000,
    kernel_n: Annotated[int, typer.Option(help="Scenarios of the new-vs-replaced kernel timings (0: skip).")] = 256,
    seed: int = 0,
    as_json: JsonOpt = False,
) -> None:
    """SF rollout and metrics throughput, each beside a plain per-scenario Python loop (ratio); CPU ms per
    scenario of one batched frenet plan; the kernels issue 27 made faster (IDM prediction, sf-opt's
    candidate check, its search and its staged search) beside the algorithms they replaced (ratio, identical
    results)."""
    # the bench functions print progress lines of their own; keep stdout clean for --json
    with contextlib.redirect_stdout(io.StringIO()):
        rollout = bench_rollout(n_scenarios=n, seed=seed, n_reference=n_reference) if n > 0 else {}
        metrics = bench_metrics(n_scenarios=n, seed=seed, n_reference=n_reference) if n > 0 else {}
        frenet = bench_frenet(n_scenarios=frenet_n, seed=seed) if frenet_n > 0 else {}
        kernels = bench_kernels(n_scenarios=kernel_n, seed=seed) if kernel_n > 0 else {}
    result = {**{f"rollout_{k}": v for k, v in rollout.items()}, **{f"metrics_{k}": v for k, v in metrics.items()},
              **{f"frenet_{k}": v for k, v in frenet.items()}, **{f"kernel_{k}": v for k, v in kernels.items()}}
    if as_json or not kernels:
        _emit(result, as_json, "speed physics")
        return
    if rollout or metrics or frenet:
        _emit({k: v for k, v in result.items() if not k.startswith("kernel_")}, False, "speed physics")
    _kernel_table(kernels)


def _kernel_table(result: dict[str, float]) -> None:
    table = Table(title=f"speed physics: kernels new vs replaced, {format_number(result['n_scenarios'])} "
                        f"scenarios, {format_number(result['sf_opt_candidates'])} sf-opt candidates each "
                        "(ms, best of 3)")
    for col in ("kernel", "new CPU", "old CPU", "old/new", "new wall", "old wall", "same"):
        table.add_column(col, justify="left" if col == "kernel" else "right")
    for name in KERNELS:
        table.add_row(name, *(format_number(result[f"{name}_{m}"]) for m in
                              ("new_cpu_ms", "old_cpu_ms", "speedup", "new_wall_ms", "old_wall_ms")),
                      "yes" if result[f"{name}_identical"] else "NO")
    out = Console()
    out.print(table)
    out.print(f"load average (1 min): {result['load_1min_start']:.2f} at the start, "
              f"{result['load_1min_end']:.2f} at the end")


def _runtime_table(result: dict[str, Any]) -> None:
    table = Table(title=f"speed llm --contention {result['hogs']}: {result['model']}, uncached planning "
                        f"request (median of {result['repeats']})")
    for col in ("configuration", "quiet s", "busy s", "busy / quiet", "threads quiet / busy", "load quiet / busy"):
        table.add_column(col, justify="left" if col == "configuration" else "right")
    for name in CONFIGS:
        entry = result.get(name)
        if not isinstance(entry, dict) or "quiet" not in entry:
            continue
        q, b = entry["quiet"], entry["busy"]
        table.add_row(name, format_number(q["median_s"]), format_number(b["median_s"]),
                      format_number(entry["busy_over_quiet"]),
                      f"{max(q['threads'])} / {max(b['threads'])}",
                      f"{q['loadavg_1min'][0]:.1f} / {b['loadavg_1min'][0]:.1f}")
    Console().print(table)
    off = result["flash_attention_off"]
    console.print(f"flash attention off (quiet): {format_number(off['median_s'])} s "
                  f"({format_number(result['flash_attention_off_over_on'])}x on); "
                  f"{result['letspi']['quiet']['self_check']}; load average at start {result['loadavg_start']}")


def _formats_table(result: dict[str, Any]) -> None:
    table = Table(title=f"{result['model']}: choice prompt per file format (load {result['loadavg_start'][0]:.2f} "
                        f"-> {result['loadavg_end'][0]:.2f})")
    for col in ("file", "MB", "prompt tokens", "prefill s", "tokens/s", "call s", "x prefill", "x call",
                "answers agree", "self-check"):
        table.add_column(col)
    for fmt, row in result.items():
        if not isinstance(row, dict):
            continue
        table.add_row(f"{fmt}: {row['file']}", f"{row['bytes'] / 1e6:.0f}", str(row["prompt_tokens"]),
                      f"{row['prefill_s']:.3f}", f"{row['tokens_per_s']:.0f}", f"{row['call_s']:.3f}",
                      f"{row.get('ratio_prefill', 1.0):.2f}", f"{row.get('ratio_call', 1.0):.2f}",
                      f"{row.get('answers_agree', len(row['answers']))}/{len(row['answers'])}", row["self_check"])
    Console().print(table)


def _levels(text: str, option: str) -> tuple[int, ...]:
    try:
        levels = tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise typer.BadParameter(f"{option} takes comma-separated integers, e.g. 1,4,16,64, got {text!r}") from None
    if not levels or min(levels) < 1:
        raise typer.BadParameter(f"{option} needs integers >= 1, got {text!r}")
    return levels


def _concurrency_table(result: dict[str, Any]) -> None:
    table = Table(title=f"speed llm --concurrency (test server, {result['server_latency_ms']} ms)")
    for col in ("concurrency", "scenarios/s", "x concurrency 1", "client overhead ms/request", "client CPU ms/request",
                "pipeline scenarios/s", "pipeline x 1"):
        table.add_column(col, justify="right")
    pipe: dict[str, Any] = result.get("pipeline") or {"concurrency": {}, "ratios": {}}
    for c, row in result["concurrency"].items():
        p = pipe["concurrency"].get(c, {})
        table.add_row(c, format_number(row["scenarios_per_s"]), format_number(result["ratios"].get(f"{c}_over_1")),
                      format_number(row.get("client_overhead_ms_per_request")),
                      format_number(row["client_cpu_ms_per_request"]), format_number(p.get("scenarios_per_s", "-")),
                      format_number(pipe["ratios"].get(f"{c}_over_1", "-")))
    Console().print(table)
    pprint({k: v for k, v in result.items() if k not in ("concurrency", "ratios", "pipeline")}, expand_all=True)


@app.command("llm")
def llm_cmd(
    model: Annotated[list[str] | None, typer.Option("--model", help="Embedded model (repeatable).")] = None,
    repeats: Annotated[int, typer.Option(help="Repetitions per latency measurement (median).")] = 2,
    phase_model: Annotated[str, typer.Option(help="Model spec of the per-phase latency run.")] = DEFAULT_LLM,
    concurrency: Annotated[str | None, typer.Option(
        help="Instead: throughput at these concurrencies (e.g. 1,4,16,64) against a local OpenAI-compatible test "
             "server with injected latency and against llama-cpp-python's server with the embedded model.")] = None,
    server_latency_ms: Annotated[float, typer.Option(help="--concurrency: the test server's mean latency.")] = 200.0,
    pipeline: Annotated[bool, typer.Option(help="--concurrency: also the whole letspi-fast planner through "
                                                "evaluate, and the 10,000-scenario projection.")] = True,
    projection_scenarios: Annotated[int, typer.Option(help="--concurrency: scenarios measured for the projection "
                                                           "(64 in flight, 64 slots, 1 s; 0: none).")] = 640,
    real_server: Annotated[bool, typer.Option(help="--concurrency: also against `python -m llama_cpp.server` "
                                                   "(SmolLM2), with its prefix reuse.")] = True,
    real_concurrency: Annotated[str, typer.Option(help="--concurrency: levels against the real server.")] = "1,4",
    contention: Annotated[int | None, typer.Option(
        help="Instead: the embedded model's uncached latency on a quiet machine and beside N CPU-bound "
             "processes (letspi's runtime vs 2 spinning threads), its self-check, and flash attention off.")] = None,
    formats: Annotated[bool, typer.Option(
        "--formats", help="Instead: the fine-tuned SmolLM2's choice call from the packaged Q4_1 file against "
                          "the F16 and Q8_0 copies (prefill, call latency, ratios, greedy agreement).")] = False,
    as_json: JsonOpt = False,
) -> None:
    """Per embedded model: latency and tokens of the physics-informed and fast prompts, warm-prefix
    and cache-hit speedups; per-phase latency; memory retrieval time at 10k and 100k experiences.
    With --concurrency: scenarios/s at each concurrency (JSON: concurrency -> scenarios_per_s)."""
    if formats:
        fmt = bench_formats(repeats=max(repeats, 3))
        if as_json:
            typer.echo(json.dumps(fmt, indent=2, default=float))
        else:
            _formats_table(fmt)
        return
    if contention is not None:
        runtime = bench_runtime((model or [DEFAULT_FAST_LLM.partition(":")[2]])[0], hogs=contention, repeats=repeats)
        if as_json:
            typer.echo(json.dumps(runtime, indent=2, default=float))
        else:
            _runtime_table(runtime)
        return
    if concurrency is not None:
        conc = bench_concurrency(_levels(concurrency, "--concurrency"), server_latency_ms, pipeline=pipeline,
                                 projection_scenarios=projection_scenarios, real_server=real_server,
                                 real_levels=_levels(real_concurrency, "--real-concurrency"))
        if as_json:
            typer.echo(json.dumps(conc, indent=2, default=float))
        else:
            _concurrency_table(conc)
        return
    models = tuple(model) if model else ("smollm2-135m", "gemma3-270m")
    result: dict[str, object] = {
        "models": bench_models(models, repeats=repeats, behaviour=False),
        "phases": bench_phases(phase_model),
        "retrieval": bench_retrieval(),
    }
    if as_json:
        typer.echo(json.dumps(result, indent=2, default=float))
        return
    Console().rule("speed llm")
    pprint(result, expand_all=True)


@app.command("closed-loop")
@planner_options(exclude=("llm_cache",))
def closed_loop_cmd(
    options: PlannerOptions,
    scenarios: Annotated[Path | None, typer.Option(help="Scenario file (default: generated traffic).")] = None,
    n: Annotated[int | None, typer.Option(
        help="Scenarios per measurement (default 256; LLM planners: 8, each simulated alone).")] = None,
    planner: Annotated[str, typer.Option(help="Planner kind (`letspi planners` lists them).")] = "sf",
    mode: Annotated[EvaluationMode, typer.Option(
        help="closed-loop-log, closed-loop-reactive or closed-loop-hybrid (no scripted events).")] = (
        EvaluationMode.LOG),
    replan_s: Annotated[float, typer.Option("--replan-s", help="Replanning period [s].")] = 1.0,
    workers: Annotated[int, typer.Option(help="Worker processes compared with 1 worker (>= 2).")] = 2,
    chunk_size: Annotated[int | None, typer.Option(
        help="Scenarios simulated together (one SUMO network or replay; default 32 with SUMO, 256 replayed).")] = (
        ClosedLoopConfig.chunk_size),
    minutes: Annotated[float, typer.Option(help="Simulated minutes when generating traffic.")] = 3.0,
    seed: int = 0,
    llm_period_s: Annotated[float, typer.Option(
        "--llm-period-s", help="LLM planners: the model at t = 0 and every this many seconds.")] = DEFAULT_LLM_PERIOD_S,
    llm_latency_s: Annotated[float | None, typer.Option(
        "--llm-latency-s", help="LLM planners: a fixed latency [s] instead of the measured one.")] = None,
    warmup: Annotated[int, typer.Option(help="LLM planners: scenarios simulated first and not counted.")] = 1,
    as_json: JsonOpt = False,
) -> None:
    """Closed-loop throughput in-process and per worker, the N-worker speed-up over 1 worker (same run),
    lockstep vs one SUMO load per scenario, SUMO-vs-metric collision flags; in closed-loop-log also the log replay
    without SUMO on the same scenarios (its speed-up over SUMO). With an LLM planner
    (dual rate): real time, i.e. the wall time per 5 s scenario simulated alone, LLM calls included (no response
    cache: every call runs the model)."""
    with user_errors():
        options = options.replace(llm_cache=False)  # LLM planners are timed uncached
        if planner_table().kind(planner).dual_rate:
            dual_rate = DualRateConfig(llm_period_s, llm_latency_s)
            result = bench_real_time(scenarios=scenarios, n=8 if n is None else n, planner=planner, options=options,
                                     mode=mode, replan_s=replan_s, dual_rate=dual_rate, warmup=warmup,
                                     minutes=minutes, seed=seed)
        else:
            result = bench_closed_loop(scenarios=scenarios, n=256 if n is None else n, planner=planner, mode=mode,
                                       replan_s=replan_s, workers=workers, chunk_size=chunk_size, minutes=minutes,
                                       seed=seed, options=options)
    _emit(result, as_json, "speed closed-loop")  # type: ignore[arg-type]


@app.command("robustness")
@planner_options(kinds=PLAIN_PLANNERS)
def robustness_cmd(
    options: PlannerOptions,
    n: Annotated[int, typer.Option(min=1, help="Scenes: random and degenerate kinds in turn.")] = 10_000,
    n_llm: Annotated[int, typer.Option(min=0, help="First scenes also planned by the LLM planners (scripted "
                                                   "backend: control flow, not model quality).")] = 300,
    seed: int = 0,
    as_json: JsonOpt = False,
) -> None:
    """Random and degenerate scenes (no neighbours, 8 neighbours overlapping the ego at t = 0, zero
    speed, a 1-lane road, NaN gaps in neighbour tracks) through every planner and every metric:
    scenes per kind, crashes and NaN per metric (both must be 0). Exit code 1 if any. The LLM planners
    run on the scripted backend (control flow, not model quality); a planner whose setting has no
    default (mlp without --mlp-weights) is skipped and said so."""
    with user_errors():
        result = bench_robustness(n, seed=seed, n_llm=n_llm, options=options,
                                  log=lambda m: console.print(m, highlight=False))
    if as_json:
        typer.echo(json.dumps(result, indent=2))
    else:
        kinds = Table(title=f"speed robustness: {format_number(n)} scenes (seed {seed})")
        kinds.add_column("kind")
        kinds.add_column("scenes", justify="right")
        for k, v in result["scenarios_by_kind"].items():
            kinds.add_row(k, format_number(v))
        out = Console()
        out.print(kinds)
        table = Table(title="per planner")
        for col in ("planner", "scenes", "crashes", "NaN values", "float metrics checked", "plans not finite",
                    "NaN aggregates", "s"):
            table.add_column(col, justify="left" if col == "planner" else "right")
        for name, row in result["planners"].items():
            table.add_row(name, format_number(row["scenarios"]), format_number(row["crashes"]),
                          format_number(row["nan_values"]), format_number(row["metrics_checked"]),
                          format_number(row["plans_not_finite"]), format_number(len(row["nan_aggregates"])),
                          format_number(row["seconds"]))
        out.print(table)
        for name, row in result["planners"].items():
            for example in row["crash_examples"]:
                out.print(f"{name} crashed on {example}", highlight=False)
            if row["nan_by_metric"]:
                out.print(f"{name} NaN by metric: {row['nan_by_metric']}", highlight=False)
        for name, reason in result["skipped"].items():
            out.print(f"{name} skipped: {reason}", highlight=False)
        out.print(f"total: {format_number(result['crashes'])} crashes, {format_number(result['nan_values'])} NaN "
                  f"({format_number(result['seconds'])} s)", highlight=False)
    if result["crashes"] or result["nan_values"] or result["nan_aggregates"]:
        raise typer.Exit(code=1)


@app.command("interrupt")
def interrupt_cmd(
    scenarios: Annotated[Path | None, typer.Option(help="Scenario file (default: generated traffic).")] = None,
    n: Annotated[int, typer.Option(help="Scenarios of the evaluate modes.")] = 3000,
    n_llm: Annotated[int, typer.Option(help="Scenarios of collect.")] = 40,
    n_labels: Annotated[int, typer.Option(help="Scenarios of train llm-data.")] = 600,
    mode: Annotated[list[str] | None, typer.Option(
        help=f"Modes to run (repeatable; default all): {', '.join(INTERRUPT_MODES)}.")] = None,
    after_s: Annotated[float, typer.Option(help="Seconds after its start each command gets Ctrl-C.")] = 10.0,
    resume: Annotated[bool, typer.Option(help="Rerun the resumable commands to completion and count.")] = True,
    llm_latency_s: Annotated[float, typer.Option(help="collect: the test server's latency per request.")] = 2.0,
    minutes: Annotated[float, typer.Option(help="Simulated minutes when generating traffic.")] = 7.0,
    seed: int = 0,
    as_json: JsonOpt = False,
) -> None:
    """Ctrl-C: seconds from SIGINT to the exit of each long command (evaluate open and closed loop,
    with workers and on Ray, collect, train llm-data, data generate, bench physics), its stop line,
    child processes left running (must be 0) and the rerun's rows and duplicates."""
    with user_errors():
        batch = bench_scenarios(scenarios, max(n, n_llm, n_labels), minutes, seed)
        result = bench_interrupt(batch, n=n, n_llm=n_llm, n_labels=n_labels, modes=mode or INTERRUPT_MODES,
                                 after_s=after_s,
                                 resume=resume, llm_latency_s=llm_latency_s,
                                 log=lambda m: console.print(m, highlight=False, markup=False))
    if as_json:
        typer.echo(json.dumps(result, indent=2))
        return
    table = Table(title=f"speed interrupt: SIGINT {format_number(after_s)} s in, {format_number(n)} scenarios "
                        f"(load {result['loadavg_start']} -> {result['loadavg_end']})")
    for col in ("mode", "s to exit", "exit", "kept", "left", "rerun rows", "dup"):
        table.add_column(col, justify="left" if col in ("mode", "kept") else "right")
    for name, row in result["modes"].items():
        if row.get("ended_before_signal"):
            table.add_row(name, "-", "-", "ended before the signal", "-", "-", "-")
            continue
        rerun = row.get("rerun") or {}
        counted = re.match(r"interrupted: (\d+ of \d+) stored", row["stop_line"])
        kept = counted.group(1) if counted else "nothing" if "nothing stored" in row["stop_line"] else row["stop_line"]
        table.add_row(name, format_number(row["seconds_to_exit"]), str(row["exit_code"]), kept,
                      format_number(row["left_running"]),
                      f"{format_number(rerun['rows'])}/{format_number(rerun['expected_rows'])}" if rerun else "-",
                      format_number(rerun["duplicates"]) if rerun else "-")
    Console().print(table)


if __name__ == "__main__":
    app(prog_name="python -m benchmarks.speed")
