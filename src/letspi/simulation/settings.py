"""The closed-loop settings a command takes, each declared once (flag, type, default, unit, help), and the
``ClosedLoopConfig`` their values make (``closed_loop_config``). The CLI turns the declarations into flags
(``letspi.cli.options.setting_options``) as it does planner options."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Final

from letspi.planners.options import PlannerOption
from letspi.simulation.config import DEFAULT_REPLAN_S, ClosedLoopConfig, EvaluationMode, HandoverConfig
from letspi.simulation.schedule import DEFAULT_LLM_PERIOD_S, RELEASE_MODES, DualRateConfig

PANEL: Final = "Closed loop"

REPLAN_S = PlannerOption[list[str] | None](
    "replan_s", list[str] | None, None,
    f"Closed loop: replanning period of every planner (S, default {DEFAULT_REPLAN_S:g}; 5 plans once) or of one "
    "planner (LABEL=S); repeatable. LLM planners replan their physics at this period and ask their model every "
    "--llm-period-s", unit="s", panel=PANEL)
WORKERS = PlannerOption("workers", int, 0, "Closed loop: worker processes (one SUMO each; 0 = this process); with "
                        "--ray, Ray actors", panel=PANEL)
RAY = PlannerOption("ray", bool, False, "Closed loop: run the --workers on Ray actors (pip install 'letspi[ray]'); "
                    "a local Ray instance unless --ray-address is given", panel=PANEL)
RAY_ADDRESS = PlannerOption[str | None]("ray_address", str | None, None, "Closed loop: join this Ray cluster (e.g. "
                                        "auto, ray://host:10001); implies --ray", panel=PANEL)
CHUNK_SIZE = PlannerOption[int | None](
    "chunk_size", int | None, None,
    "Closed loop: scenarios simulated together and written per part (in no key: results agree to float "
    "rounding; smaller chunks lose less when a run is killed). Default: 32 with SUMO, 256 for the replay",
    panel=PANEL)
SUMO_GUI = PlannerOption("sumo_gui", bool, False, "Closed loop: watch the simulation in sumo-gui over TraCI "
                         "(needs SUMO's sumo-gui; slow)", panel=PANEL)
SIMULATOR = PlannerOption("simulator", str, "auto", "Closed loop: auto (replay in closed-loop-log, else SUMO), "
                          "replay (closed-loop-log in NumPy: neighbours replay their log; the same trajectories and "
                          "metrics as SUMO without SUMO's own collision flag, several times faster) or sumo",
                          choices=("auto", "replay", "sumo"), panel=PANEL)
LLM_PERIOD_S = PlannerOption[float | None](
    "llm_period_s", float | None, None,
    f"Closed loop, LLM planners (dual rate): ask the model at t = 0 and then every this many seconds (default "
    f"{DEFAULT_LLM_PERIOD_S:g}; 5: at t = 0 only); meanwhile the physics and the shield replan every --replan-s "
    "with the answer in force. In the LLM planners' keys", unit="s", panel=PANEL)
LLM_LATENCY_S = PlannerOption[float | None](
    "llm_latency_s", float | None, None,
    "Closed loop, LLM planners: an answer takes effect this many seconds (simulated) after its call: "
    "reproducible, in the key. Default: the measured latency (the simulation waits for the wall clock while an "
    "answer is out)", unit="s", panel=PANEL)
RELEASE = PlannerOption("release", str, "checks", "Closed loop, LLM planners with the decision step (dual rate): "
                        "when a preset held since an earlier call gives way to the defaults at a replan: checks (the "
                        "gate would not consult, or the defaults pass every check), prediction (the defaults pass "
                        "the checks against the prediction) or off (held until the next answer). In the LLM "
                        "planners' keys", choices=RELEASE_MODES, panel=PANEL)
HANDOVER_LANES = PlannerOption[int | None](
    "handover_lanes", int | None, None,
    "closed-loop-hybrid: a neighbour behind the ego is handed to SUMO when its lane is one the ego's box covers "
    "or at most this many lanes beside those (default 0; 1 = the adjacent lanes too)", panel=PANEL)
#: every closed-loop setting of ``letspi evaluate``
CLOSED_LOOP_OPTIONS: Final[tuple[PlannerOption[Any], ...]] = (
    REPLAN_S, WORKERS, RAY, RAY_ADDRESS, SUMO_GUI, SIMULATOR, CHUNK_SIZE, HANDOVER_LANES, LLM_PERIOD_S, LLM_LATENCY_S,
    RELEASE)


def parse_replan_options(values: Sequence[str] | None, labels: Sequence[str]) -> tuple[float, dict[str, float]]:
    """``--replan-s`` values: ``S`` (every planner) and ``LABEL=S`` (one planner); returns (default period,
    {label: period}). Unknown labels and unparsable values are errors."""
    default = DEFAULT_REPLAN_S
    own: dict[str, float] = {}
    for text in values or []:
        label, sep, value = text.rpartition("=")
        try:
            period = float(value)
        except ValueError:
            raise ValueError(f"--replan-s takes S or LABEL=S (seconds), got {text!r}") from None
        if not sep:
            default = period
        elif label not in labels:
            raise ValueError(f"--replan-s {text}: no planner labelled {label!r} (planners: {', '.join(labels)})")
        else:
            own[label] = period
    return default, own


def closed_loop_config(mode: EvaluationMode, values: Mapping[str, Any], labels: Sequence[str],
                       concurrency: int | None = None) -> ClosedLoopConfig | None:
    """The ``ClosedLoopConfig`` of the settings ``values`` (option name -> value; absent: the default), None in
    open loop, where a setting given is refused; ``ClosedLoopConfig`` checks the values."""
    v = {o.name: values.get(o.name, o.default) for o in CLOSED_LOOP_OPTIONS}
    if not mode.closed_loop:
        given = [o.cli_flag for o in CLOSED_LOOP_OPTIONS if v[o.name] != o.default and o is not CHUNK_SIZE
                 and o is not HANDOVER_LANES]
        if given:
            raise ValueError(f"{', '.join(given)} apply to the closed-loop modes only (--mode closed-loop-log, "
                             "closed-loop-reactive or closed-loop-hybrid)")
        return None
    if concurrency is not None:
        raise ValueError("--concurrency applies to open loop; in closed loop scenarios run in parallel with --workers "
                         "(one planner per worker: for LLM planners, about one per model-server slot)")
    default, own = parse_replan_options(v["replan_s"], labels)
    lanes = v["handover_lanes"]
    if lanes is not None and mode is not EvaluationMode.HYBRID:
        raise ValueError(f"--handover-lanes applies to --mode closed-loop-hybrid only, not {mode}")
    period = v["llm_period_s"]
    return ClosedLoopConfig(
        mode=mode, replan_s=default, planner_replan_s=own, workers=v["workers"],
        ray_address=v["ray_address"] or ("local" if v["ray"] else None), sumo_gui=v["sumo_gui"],
        chunk_size=v["chunk_size"], handover=HandoverConfig() if lanes is None else HandoverConfig(lanes=lanes),
        dual_rate=DualRateConfig(DEFAULT_LLM_PERIOD_S if period is None else period, v["llm_latency_s"],
                                 release=v["release"]),
        simulator=v["simulator"])
