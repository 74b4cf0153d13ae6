"""``letspi benchmark``: versioned suites (``list``, ``show``, ``run``); one table over several runs (``summary``);
windows a paired test needs (``power``); the paper's Tables III-VI on the suites (``paper``)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import typer

from letspi.assembly.planner_table import planner_table
from letspi.benchmark.leaderboard import to_markdown
from letspi.benchmark.paper import DEFAULT_SUITES, FAST_MODELS, MEMORY_MODELS, TABLES, PaperSettings, run_paper
from letspi.benchmark.power import alternative, mcnemar_power, windows_needed
from letspi.benchmark.run import default_planners, run_suite
from letspi.benchmark.suites import SUITES, ExternalSuite, GeneratedTraffic, external_suites, get_any_suite, get_suite
from letspi.benchmark.summary import load_boards, summary_markdown
from letspi.cli.common import command_line, console, progress_bar, user_errors
from letspi.cli.evaluate import progress_factory
from letspi.cli.options import planner_options
from letspi.fsutil import writer_lock
from letspi.planners.options import PlannerOptions
from letspi.simulation.settings import RELEASE

app = typer.Typer(help="Versioned benchmark suites: list, show, run; power of a paired comparison.",
                  no_args_is_help=True, rich_markup_mode=None)


@app.command("list")
def list_suites() -> None:
    """List every suite. Its id (name@version-digest), windows, modes and what is scripted in its traffic."""
    for suite in SUITES.values():
        modes = ", ".join(m.slug + (f" ({m.n_windows:,d})" if m.n_windows else "") for m in suite.modes)
        typer.echo(f"{suite.suite_id:34s} {suite.extraction.n_windows:>6,d} windows  {modes}")
        typer.echo(f"    {suite.description}; {suite.scripted}")
    for other in external_suites().values():
        typer.echo("\n".join(other.list_lines()))


@app.command("show")
def show(
    suite: Annotated[str, typer.Argument(help="Suite name (or its full id).")],
    as_json: Annotated[bool, typer.Option("--json", help="The full definition as JSON.")] = False,
) -> None:
    """Show everything a suite pins. Traffic (resolved configuration), extraction, modes, metrics, digest."""
    with user_errors():
        found = get_any_suite(suite)
    if found.name in external_suites():
        other = external_suites()[found.name]
        typer.echo(json.dumps({"id": other.suite_id, **other.definition()}, indent=2, sort_keys=True) if as_json
                   else "\n".join(other.show_lines()))
        return
    s = get_suite(suite)
    if as_json:
        typer.echo(json.dumps({"id": s.suite_id, **s.definition()}, indent=2, sort_keys=True))
        return
    typer.echo(f"{s.suite_id}: {s.description}")
    data = s.data
    if isinstance(data, GeneratedTraffic):
        typer.echo(f"traffic: preset {data.preset}, layout {data.layout}, seeds {', '.join(map(str, data.seeds))}, "
                   f"{data.minutes:g} min each (recordings of {data.recording_minutes:g} min), "
                   f"{data.lanes_per_direction} lanes per direction"
                   + (f", overrides {dict(data.overrides)}" if data.overrides else ""))
    else:
        typer.echo(f"traffic: your HighD recordings {', '.join(f'{r:02d}' for r in data.recording_ids)} "
                   f"(file digests {'pinned' if data.file_digests else 'not pinned yet'})")
    typer.echo(f"events: {s.scripted}")
    ex = s.extraction
    typer.echo(f"windows: {ex.n_windows}, focus {ex.focus}" + (f" (share {ex.critical_share:g} with a conflict)"
                                                              if ex.critical_share else "")
               + f", seed {ex.seed}, stride {ex.stride_frames} frames")
    for m in s.modes:
        extra = "" if m.replan_s is None else (
            f": replanning every {m.replan_s:g} s; LLM planners ask their model every {m.llm_period_s:g} s, "
            f"answers in force after {m.llm_latency_s:g} s")
        typer.echo(f"mode: {m.mode}{extra}")
    typer.echo(f"size: {s.sizing}")
    typer.echo(f"metrics: {json.dumps(s.metrics.recorded(), sort_keys=True)}")
    typer.echo("full definition (what the digest covers): letspi benchmark show " + s.name + " --json")


@app.command("run")
@planner_options()
def run(
    suite: Annotated[str, typer.Argument(help="Suite name (or its full id).")],
    options: PlannerOptions,
    planner: Annotated[list[str] | None, typer.Option(
        help="Planner (repeatable; default: every built-in planner without a language model). "
             + planner_table().planner_help())] = None,
    out: Annotated[Path | None, typer.Option(help="Results directory (default: benchmark/SUITE-ID).")] = None,
    highd: Annotated[Path | None, typer.Option(
        help="Real-data suites: your HighD directory (NN_tracks.csv, ...).")] = None,
    allow_other_files: Annotated[bool, typer.Option(
        help="Real-data suites: run even if your files differ from those the suite pins (warns).")] = False,
    workers: Annotated[int, typer.Option(
        min=1, help="Processes for generation, open-loop planners and closed-loop simulation.")] = 2,
    reports: Annotated[bool, typer.Option(help="Write each mode's report.html.")] = True,
    mode: Annotated[list[str] | None, typer.Option(
        "--mode", help="Only this mode of the suite (its slug, e.g. open-loop or closed-loop-log-0.2s; "
                       "repeatable; default: all): the leaderboard then holds these modes.")] = None,
    limit: Annotated[int | None, typer.Option(
        min=1, help="A quick try: only the first N windows of each mode, in a directory of its own (default: "
                    "benchmark/SUITE-ID-first-N); its leaderboard says it is not the suite's result.")] = None,
    release: Annotated[str, typer.Option(help=RELEASE.help)] = RELEASE.default,
) -> None:
    """Run a suite and write its leaderboard. Generates the suite's data (cached), evaluates the planners
    in its modes and writes leaderboard.json / .md / .html with 95 % intervals and paired deltas against sf."""
    with user_errors():
        found = get_any_suite(suite)
    if found.name in external_suites():
        _run_external(external_suites()[found.name], options, planner, out, workers, reports)
        return
    with user_errors(resumes=True):  # the data is cached, each mode's evaluation resumes
        s = get_suite(suite)
        planners = planner or default_planners()
        target = out or Path("benchmark") / (s.suite_id if limit is None else f"{s.suite_id}-first-{limit}")
        with writer_lock(target, command_line()), progress_bar() as bar:
            result = run_suite(s, planners, target, options=options, highd_dir=highd,
                               allow_other_files=allow_other_files, workers=workers, reports=reports,
                               progress_factory=progress_factory(bar), log=bar.console.print,
                               modes=mode, limit=limit, release=release)
    typer.echo(to_markdown(result.board))
    t = result.timing
    for slug, seconds in result.planner_s.items():
        console.print(f"{slug}: " + ", ".join(f"{name} {s:.1f} s" for name, s in seconds.items()))
    console.print(f"data: {'reused from the cache' if result.data.reused else 'made'} (generation "
                  f"{t['generation_s']:.1f} s, extraction {t['extraction_s']:.1f} s); total {t['total_s']:.1f} s; "
                  f"results in {target}/ (leaderboard.json, leaderboard.md, leaderboard.html, timing.json)")


def _run_external(s: ExternalSuite, options: PlannerOptions, planner: list[str] | None, out: Path | None,
                  workers: int, reports: bool) -> None:
    """``run`` of a companion's suite (highway-env's): its own runner, resumable."""
    with user_errors(resumes=True):
        target = out or Path("benchmark") / s.suite_id
        with writer_lock(target, command_line()), progress_bar() as bar:
            def factory(name: str, total: int) -> Callable[[int], None]:
                task = bar.add_task(name, total=total)
                return lambda k: bar.advance(task, k)

            table = s.run(planner, target, options=options, workers=workers, reports=reports, progress=factory,
                          log=bar.console.print)
    typer.echo(table)


@app.command("summary")
def summary(
    results: Annotated[list[Path], typer.Argument(help="Results directories of suite runs (each with its "
                                                       "leaderboard.json), one column group each.")],
    planner: Annotated[list[str] | None, typer.Option(
        "--planner", help="Only these planners, in this order (repeatable; default: all, as first seen).")] = None,
    mode: Annotated[list[str] | None, typer.Option(
        "--mode", help="Only this mode (slug, e.g. open-loop; repeatable; default: all).")] = None,
) -> None:
    """One table over several suites' leaderboards. Per planner and suite mode: CR at fault % (95 % CI), the
    paired McNemar p against the suite's reference and SR %; then which planners another dominates (both
    intervals apart). Reads the leaderboards only: nothing is rerun."""
    with user_errors():
        text = summary_markdown(load_boards(results), planner, mode)
    typer.echo(text, nl=False)


@app.command("power")
def power(
    results: Annotated[Path | None, typer.Argument(
        help="A suite's results directory (its leaderboard.json): the discordance each planner measured "
             "against the reference.")] = None,
    discordance_pct: Annotated[list[float] | None, typer.Option(
        "--discordance-pct", help="Or given discordances [% of windows] (repeatable).")] = None,
    difference_pts: Annotated[float, typer.Option(help="Difference of the CRs to detect [points].")] = 1.0,
    target_power: Annotated[float, typer.Option("--power", help="Power to reach.")] = 0.8,
    alpha: Annotated[float, typer.Option(help="Level of the two-sided exact McNemar test.")] = 0.05,
) -> None:
    """Windows a paired comparison needs to detect a CR difference. Exact McNemar power; windows of one
    vehicle are correlated, so the count is multiplied by the measured design effect of the discordant
    windows, and the power at a run's n is that of n / design effect independent windows."""
    with user_errors():
        rows: list[tuple[str, float, int | None, float]] = []
        if results is not None:
            board = json.loads((results / "leaderboard.json").read_text())
            for slug, mode in board["modes"].items():
                for name, entry in mode["paired"]["planners"].items():
                    cr = entry["cr_pct"]
                    psi = (cr["n_only_planner"] + cr["n_only_reference"]) / max(cr["n_pairs"], 1)
                    rows.append((f"{slug} {name} vs {mode['paired']['reference']} (n {cr['n_pairs']})", psi,
                                 cr["n_pairs"], cr.get("discordant_design_effect") or 1.0))
        rows += [(f"discordance {d:g} %", d / 100.0, None, 1.0) for d in discordance_pct or []]
        if not rows:
            raise ValueError("give a results directory or --discordance-pct")
    d = difference_pts / 100.0
    typer.echo(f"| comparison | discordance % | windows for power {target_power:g} (independent) | design effect "
               "| windows x design effect | power at its n / design effect |")
    typer.echo("|---|---:|---:|---:|---:|---:|")
    for label, psi, n, deff in rows:
        need = windows_needed(psi, d, target_power, alpha)
        scaled = "–" if need is None else f"{round(need * max(deff, 1.0)):,d}"
        at_n = f"{mcnemar_power(round(n / max(deff, 1.0)), *alternative(psi, d), alpha):.2f}" if n else "–"
        typer.echo(f"| {label} | {100 * psi:.2f} | {need if need is not None else '> 200,000'} | {deff:.2f} "
                   f"| {scaled} | {at_n} |")


@app.command("paper")
@planner_options(exclude=("prompt_style",))
def paper(
    options: PlannerOptions,
    suite: Annotated[list[str] | None, typer.Option(
        "--suite", help=f"Suite to draw windows from (repeatable; default: {', '.join(DEFAULT_SUITES)}).")] = None,
    windows: Annotated[int, typer.Option(help="Evaluated windows per suite.")] = PaperSettings.eval_windows,
    memory_windows: Annotated[int, typer.Option(
        help="Windows per suite (of other vehicles) each memory collection runs on.")] = PaperSettings.memory_windows,
    memory_phase_windows: Annotated[int, typer.Option(
        help="Evaluated windows per suite letspi-memory (Table III's memory phase) plans too.")
    ] = PaperSettings.memory_phase_windows,
    memory_share: Annotated[float, typer.Option(
        help="Share of each suite's ego vehicles held for memory collection.")] = PaperSettings.memory_share,
    seed: Annotated[int, typer.Option(help="Seed of the vehicle split and the window draws.")] = PaperSettings.seed,
    memory_model: Annotated[list[str] | None, typer.Option(
        "--memory-model", help=f"Table VI memory model (repeatable; default: {', '.join(MEMORY_MODELS)}).")] = None,
    fast_model: Annotated[list[str] | None, typer.Option(
        "--fast-model", help=f"Table VI fast model (repeatable; default: {', '.join(FAST_MODELS)}).")] = None,
    prompt_style: Annotated[str, typer.Option(
        help="Prompt style of every LLM row (choice: the shipped decision step; paper: the paper's prompts "
             "with the memories as few-shot examples).")] = PaperSettings.prompt_style,
    table: Annotated[list[str] | None, typer.Option(
        "--table", help=f"Only this table (repeatable; {', '.join(TABLES)}; default: all).")] = None,
    out: Annotated[Path, typer.Option(help="Results directory.")] = Path("benchmark/paper"),
    workers: Annotated[int, typer.Option(min=1, help="Processes for the planners without a model.")] = 2,
) -> None:
    """The paper's Tables III-VI on the pinned suites (docs/reproduction.md): baselines, memory and fast
    phase; w/o Ref, w/o GA, FS; memory size; memory x fast model. Resumable: rerun the same command.
    Writes OUT/paper.md and OUT/paper.json (the paper's numbers beside letspi's, intervals, paired tests)."""
    with user_errors(resumes=True):
        settings = PaperSettings(
            suites=tuple(suite or DEFAULT_SUITES), eval_windows=windows, memory_windows=memory_windows,
            memory_phase_windows=memory_phase_windows, memory_share=memory_share, seed=seed,
            memory_models=tuple(memory_model or MEMORY_MODELS), fast_models=tuple(fast_model or FAST_MODELS),
            prompt_style=prompt_style)
        with writer_lock(out, command_line()), progress_bar() as bar:
            result = run_paper(settings, out, options.replace(prompt_style=prompt_style), tables=table or TABLES,
                               workers=workers, progress_factory=progress_factory(bar), log=bar.console.print)
    typer.echo((out / "paper.md").read_text())
    console.print(f"total {result.timing['total_s']:.1f} s; results in {out}/ (paper.md, paper.json, timing.json)")
