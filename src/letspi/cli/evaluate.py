"""``letspi evaluate``: run planners on scenarios and write the paper-style table."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.progress import Progress

from letspi.assembly.planner_table import planner_table
from letspi.assembly.planners import BuiltPlanner, build_planners, planner_kinds
from letspi.cli.common import (
    ConcurrencyOpt,
    command_line,
    console,
    print_run,
    progress_bar,
    run_progress,
    user_errors,
)
from letspi.cli.options import planner_options
from letspi.evaluation.closed_loop import (
    ScriptedNeighbours,
    evaluate_closed_loop,
    events_directory,
    parse_replan_options,
    scripted_for,
)
from letspi.evaluation.harness import (
    ProgressCallback,
    ProgressFactory,
    read_summary,
    stored_rows,
    summary_markdown,
)
from letspi.evaluation.harness import evaluate as run_evaluation
from letspi.fsutil import writer_lock
from letspi.metrics.aggregate import AggValue
from letspi.planners.options import PlannerOptions
from letspi.scenario.store import count_scenarios, load_scenarios
from letspi.scenario.types import ScenarioBatch
from letspi.simulation.config import ClosedLoopConfig, EvaluationMode, HandoverConfig
from letspi.simulation.schedule import DEFAULT_LLM_PERIOD_S, DualRateConfig

PlannerOpt = Annotated[list[str], typer.Option(help=planner_table().planner_help())]


def load_limited(scenarios: Path, limit: int | None) -> ScenarioBatch:
    """The first ``limit`` scenarios of a file (all when None)."""
    n_total = count_scenarios(scenarios)
    return load_scenarios(scenarios, None if limit is None else np.arange(min(limit, n_total)))


ModeOpt = Annotated[EvaluationMode, typer.Option(
    help="open-loop (the paper's protocol: one plan at t = 0, neighbours replay the log), closed-loop-log (the "
         "ego follows its plan in SUMO and replans every --replan-s; neighbours replay the log), "
         "closed-loop-reactive (every neighbour is driven by SUMO's IDM from t = 0 and reacts to the ego; the "
         "recorded hard brakes and cut-ins are lost) or closed-loop-hybrid (neighbours replay the log while "
         "ahead of the ego and are handed to SUMO's IDM, capped at their recorded speed, once behind it in a lane "
         "its box covers; actors of scripted events, see --events, replay the log throughout).")]
EventsOpt = Annotated[str | None, typer.Option(
    "--events", help="closed-loop-hybrid: HighD directory with the NN_events.csv of the scenarios' recordings "
                     "(their actors keep the log), or 'none'. Default: the directory the scenario file was cut "
                     "from (its provenance), if it still exists.")]
ReplanOpt = Annotated[list[str] | None, typer.Option(
    "--replan-s", help="Closed loop: replanning period [s] of every planner (S, default 1.0; 5 plans once) or of "
                       "one planner (LABEL=S); repeatable. LLM planners replan their physics at this period and ask "
                       "their model every --llm-period-s.")]
WorkersOpt = Annotated[int, typer.Option(
    help="Closed loop: worker processes (one SUMO each; 0 = this process). With --ray: Ray actors.")]
RayOpt = Annotated[bool, typer.Option(
    "--ray", help="Closed loop: run the --workers on Ray actors (pip install 'letspi[ray]'); a local Ray instance "
                  "unless --ray-address is given.")]
RayAddressOpt = Annotated[str | None, typer.Option(
    help="Closed loop: join this Ray cluster (e.g. auto, ray://host:10001); implies --ray.")]
ChunkSizeOpt = Annotated[int | None, typer.Option(
    help="Closed loop: scenarios simulated together (in one SUMO network or replay) and written per part (not in "
         "any key: results agree to float rounding; smaller chunks lose less when a run is killed). Default: 32 "
         "with SUMO, 256 for the replay.")]
SumoGuiOpt = Annotated[bool, typer.Option(
    "--sumo-gui", help="Closed loop: watch the simulation in sumo-gui over TraCI (needs SUMO's sumo-gui; slow).")]
SimulatorOpt = Annotated[str, typer.Option(
    "--simulator", help="Closed loop: auto (replay in closed-loop-log, else SUMO), replay (closed-loop-log in "
                        "NumPy: the neighbours only replay their log; the same trajectories and metrics as SUMO, "
                        "without SUMO's own collision flag, several times faster) or sumo.")]
LlmPeriodOpt = Annotated[float | None, typer.Option(
    "--llm-period-s", help="Closed loop, LLM planners (dual rate): ask the model at t = 0 and then every this many "
                           f"seconds (default {DEFAULT_LLM_PERIOD_S:g}: two calls per 5 s scenario; 5: at t = 0 only); "
                           "meanwhile the physics and the shield replan every --replan-s with the answer in force. "
                           "In the LLM planners' keys.")]
LlmLatencyOpt = Annotated[float | None, typer.Option(
    "--llm-latency-s", help="Closed loop, LLM planners: an answer takes effect this many seconds (simulated) after "
                            "its call: reproducible, in the key. Default: the measured latency (the model runs beside "
                            "the simulation, which waits for the wall clock while an answer is out).")]
LlmReleaseOpt = Annotated[str, typer.Option(
    "--release", help="Closed loop, LLM planners with the decision step (dual rate): when a preset held since an "
                      "earlier call gives way to the defaults at a replan: checks (the gate would not consult, or "
                      "the defaults pass every check), prediction (the defaults pass the checks against the "
                      "prediction) or off (held until the next answer). In the LLM planners' keys.")]
HandoverLanesOpt = Annotated[int | None, typer.Option(
    help="closed-loop-hybrid: a neighbour behind the ego is handed to SUMO when its lane is one the ego's box "
         "covers or at most this many lanes beside those (default 0; 1 = the adjacent lanes too).")]


ReferenceOpt = Annotated[str | None, typer.Option(
    help="Planner label every other planner of the directory is compared with, on the same windows (metrics.json "
         "\"paired\", metrics.md): differences with 95 % intervals, windows only one of them fails, exact McNemar "
         "p. Default: sf when the directory has it, else the first --planner.")]
OutDirOpt = Annotated[Path, typer.Option(help="Output directory (rerunning resumes; another dataset, metrics "
                                                "configuration or planner configuration is refused).")]
def closed_loop_settings(mode: EvaluationMode, replan_s: list[str] | None, labels: list[str], workers: int,
                         ray: str | None, sumo_gui: bool, chunk_size: int | None = ClosedLoopConfig.chunk_size,
                         concurrency: int | None = None,
                         handover_lanes: int | None = None, llm_period_s: float | None = None,
                         llm_latency_s: float | None = None, simulator: str = "auto",
                         llm_release: str = "checks") -> ClosedLoopConfig | None:
    """The closed-loop settings of the options (None in open loop, where they are refused); the
    ``ClosedLoopConfig`` checks its values. ``ray``: None (no Ray), ``local`` or a cluster address."""
    if not mode.closed_loop:
        given = [name for name, on in (("--replan-s", bool(replan_s)), ("--workers", workers != 0),
                                       ("--ray", ray is not None), ("--sumo-gui", sumo_gui),
                                       ("--llm-period-s", llm_period_s is not None),
                                       ("--llm-latency-s", llm_latency_s is not None),
                                       ("--release", llm_release != "checks"),
                                       ("--simulator", simulator != "auto")) if on]
        if given:
            raise ValueError(f"{', '.join(given)} apply to the closed-loop modes only (--mode closed-loop-log, "
                             "closed-loop-reactive or closed-loop-hybrid)")
        return None
    if concurrency is not None:
        raise ValueError("--concurrency applies to open loop; in closed loop scenarios run in parallel with --workers "
                         "(one planner per worker: for LLM planners, about one per model-server slot)")
    default, own = parse_replan_options(replan_s, labels)
    if handover_lanes is not None and mode is not EvaluationMode.HYBRID:
        raise ValueError(f"--handover-lanes applies to --mode closed-loop-hybrid only, not {mode}")
    handover = HandoverConfig() if handover_lanes is None else HandoverConfig(lanes=handover_lanes)
    dual_rate = DualRateConfig(DEFAULT_LLM_PERIOD_S if llm_period_s is None else llm_period_s, llm_latency_s,
                               release=llm_release)
    return ClosedLoopConfig(mode=mode, replan_s=default, planner_replan_s=own, workers=workers, ray_address=ray,
                            sumo_gui=sumo_gui, chunk_size=chunk_size, handover=handover, dual_rate=dual_rate,
                            simulator=simulator)  # type: ignore[arg-type]


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


def progress_factory(bar: Progress) -> ProgressFactory:
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
        return run_evaluation(planners, batch, out, scenarios_file=str(scenarios),
                              progress_factory=progress_factory(bar), concurrency=concurrency, on_run=print_run,
                              reference=reference)


@planner_options()
def evaluate(
    scenarios: Annotated[Path, typer.Option(help="Scenario file (from `letspi data scenarios`).")],
    planner: PlannerOpt,
    out: OutDirOpt,
    options: PlannerOptions,
    limit: Annotated[int | None, typer.Option(help="Only the first N scenarios.")] = None,
    concurrency: ConcurrencyOpt = None,
    mode: ModeOpt = EvaluationMode.OPEN_LOOP,
    replan_s: ReplanOpt = None,
    workers: WorkersOpt = ClosedLoopConfig.workers,
    ray: RayOpt = False,
    ray_address: RayAddressOpt = None,
    sumo_gui: SumoGuiOpt = ClosedLoopConfig.sumo_gui,
    simulator: SimulatorOpt = ClosedLoopConfig.simulator,
    chunk_size: ChunkSizeOpt = ClosedLoopConfig.chunk_size,
    events: EventsOpt = None,
    handover_lanes: HandoverLanesOpt = None,
    llm_period_s: LlmPeriodOpt = None,
    llm_latency_s: LlmLatencyOpt = None,
    release: LlmReleaseOpt = "checks",
    reference: ReferenceOpt = None,
) -> None:
    """Evaluate planners: DIR/metrics.json, DIR/metrics.md and per-scenario Parquet parts with the plans
    (open loop, or closed loop in SUMO with --mode)."""
    with user_errors(resumes=True) as tally, writer_lock(out, command_line()):
        labels = [label for label, _ in planner_kinds(planner)]
        closed = closed_loop_settings(mode, replan_s, labels, workers, ray_address or ("local" if ray else None),
                                      sumo_gui, chunk_size, concurrency, handover_lanes, llm_period_s, llm_latency_s,
                                      simulator, release)
        batch = load_limited(scenarios, limit)
        tally.track(len(labels) * len(batch), lambda: min(stored_rows(out, labels), len(labels) * len(batch)))
        scripted = scripted_neighbours_of(mode, events, scenarios, batch)
        if scripted is not None:
            console.print(scripted.describe())
        planners = build_planners(planner, options)
        _run_planners(planners, batch, out, closed, scenarios, scripted, concurrency, reference)
    if closed is not None:
        typer.echo(closed_loop_line(closed, planners) + "\n")
    typer.echo(summary_markdown(read_summary(out), [p.name for p in planners]))
    console.print(f"results in {out}/ (metrics.json, metrics.md, per_scenario/; keys in run.json and "
                  "per_scenario/*/config.json)")
