"""Settings of the closed-loop engine (typed, frozen; SI units in the names).

Modes
-----
* ``closed-loop-log``: the neighbours replay their recorded trajectories (they cannot react);
  the ego follows its planner and replans from the simulated history.
* ``closed-loop-reactive``: up to t = 0 every vehicle replays the log; from then on the neighbours
  are driven by SUMO's car-following (IDM) and sublane lane-change (SL2015) models, with a desired
  speed and a time headway estimated from each one's history, and react to the ego (nuPlan's
  reactive agents). The recorded events (hard brakes, cut-ins) that made a window critical are
  gone: the released leader drives on at its desired speed.
* ``closed-loop-hybrid``: the log where the ego cannot influence it, reactive where it can. A
  neighbour replays its log while it is ahead of the ego (or beside it, or in a lane the ego does
  not cover); once it is behind the ego in a lane the ego's box covers (``HandoverConfig``) it is
  handed to SUMO for good (same driver model as ``closed-loop-reactive``, capped at its recorded
  speed so that it deviates from the log only to react to the ego). The actors of
  scripted events (``NN_events.csv``, the ``scripted_nbr`` mask of a run) replay their log all
  along, wherever they are. So a leader's recorded hard brake still happens, and a follower reacts
  to what the ego does instead of rear-ending it on the recorded path.

Open loop (the paper's protocol) is the fourth ``EvaluationMode``, run by the harness
(``letspi.evaluation.harness``), not by this package: ``ClosedLoopConfig`` refuses it.

``ClosedLoopConfig`` is the one closed-loop settings type: ``letspi evaluate --mode closed-loop-*``
builds it from the flags (and it validates them, once), the evaluation layer records what of it
changes answers, and the engine reads the mode and each planner's replanning period from it alone.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Final, Literal

from letspi.constants import DT_S, N_FUTURE
from letspi.simulation.schedule import DualRateConfig
from letspi.suggest import unknown


class EvaluationMode(StrEnum):
    """How planners are evaluated: open loop (the paper's protocol) or one of the closed-loop modes above."""

    OPEN_LOOP = "open-loop"
    LOG = "closed-loop-log"
    REACTIVE = "closed-loop-reactive"
    HYBRID = "closed-loop-hybrid"

    @property
    def closed_loop(self) -> bool:
        return self is not EvaluationMode.OPEN_LOOP

    @classmethod
    def _missing_(cls, value: object) -> EvaluationMode:
        raise ValueError(unknown("evaluation mode", value, [m.value for m in cls]))

    @property
    def has_drivers(self) -> bool:
        """Whether some neighbours are driven by SUMO's driver models (the driver model changes answers)."""
        return self in (EvaluationMode.REACTIVE, EvaluationMode.HYBRID)


CLOSED_LOOP_MODES: tuple[EvaluationMode, ...] = tuple(m for m in EvaluationMode if m.closed_loop)
DEFAULT_REPLAN_S = 1.0
#: Plans further than this beyond a road edge are not followed (the ego keeps its velocity instead).
OFF_ROAD_MARGIN_M = 15.0


@dataclass(frozen=True)
class DriverModelConfig:
    """SUMO driver parameters of released neighbours (``closed-loop-reactive`` and ``closed-loop-hybrid``).

    Fixed for everyone: IDM with ``accel_mps2`` / ``decel_mps2`` (comfortable), braking up to
    ``emergency_decel_mps2``, standstill gap ``min_gap_m``, no driver imperfection.
    Estimated per vehicle from its history (``letspi.simulation.drivers``): the desired speed (the
    highest speed it drove, clipped to ``desired_speed_bounds_mps``) and the time headway (the
    ``headway_quantile`` of its observed time gaps to an in-path leader, clipped to
    ``headway_bounds_s``; ``default_headway_s`` when it never had one within ``max_leader_gap_s``).
    """

    accel_mps2: float = 1.5
    decel_mps2: float = 3.0
    emergency_decel_mps2: float = 9.0
    min_gap_m: float = 2.0
    default_headway_s: float = 1.5
    headway_bounds_s: tuple[float, float] = (0.6, 2.5)
    headway_quantile: float = 0.2
    max_leader_gap_s: float = 4.0
    desired_speed_bounds_mps: tuple[float, float] = (5.0, 50.0)

    def __post_init__(self) -> None:
        lo, hi = self.headway_bounds_s
        if not 0 < lo <= self.default_headway_s <= hi:
            raise ValueError(
                f"need 0 < headway_bounds_s[0] <= default_headway_s <= headway_bounds_s[1], "
                f"got {self.headway_bounds_s}, {self.default_headway_s}"
            )
        if lo < DT_S:
            raise ValueError(f"headways below the step length ({DT_S} s) make SUMO brake unrealistically")
        if not 0.0 <= self.headway_quantile <= 1.0:
            raise ValueError(f"headway_quantile must be in [0, 1], got {self.headway_quantile}")
        if min(self.accel_mps2, self.decel_mps2, self.emergency_decel_mps2) <= 0 or self.min_gap_m < 0:
            raise ValueError("accelerations must be > 0 and min_gap_m >= 0")
        if self.emergency_decel_mps2 < self.decel_mps2:
            raise ValueError("emergency_decel_mps2 must be >= decel_mps2")


@dataclass(frozen=True)
class HandoverConfig:
    """When ``closed-loop-hybrid`` hands a log-replayed neighbour to SUMO (``letspi.simulation.handover``).

    Checked every frame after t = 0 on the previous frame's simulated positions. A neighbour that is
    not a scripted-event actor is handed over when both hold:

    * its lane (lane of its centre) is one the ego's box covers (the ego's lane; during a lane
      change also the lane it moves into), or at most ``lanes`` lanes beside those (``lanes = 1``:
      the adjacent lanes too);
    * its front bumper is at least ``behind_m`` behind the ego's rear bumper (0: fully behind; a
      vehicle beside the ego keeps replaying its log: the ego's lane change into it is the ego's fault).

    The hand-over is final (no return to the log: the log position would jump), so no hysteresis
    band is needed; position and speed stay continuous (SUMO starts from the vehicle's place and
    its last speed).

    ``follow_log_speed``: a handed-over vehicle keeps driving at its recorded speed of each frame
    unless SUMO's car following (the ego or another simulated vehicle ahead) needs it slower
    (``setSpeed`` under speed mode 25: the safe speed bounds the commanded one, acceleration and
    deceleration bounds do not); SUMO's lane-change model moves it laterally. Without it the
    vehicle drives at its estimated desired speed, and a vehicle that a car outside the simulated
    neighbour slots held back in the log then speeds up beyond anything recorded. Once its log
    ends (it left the recorded road section) SUMO's driver model alone drives it.
    """

    lanes: int = 0
    behind_m: float = 0.0
    follow_log_speed: bool = True

    def __post_init__(self) -> None:
        if self.lanes < 0:
            raise ValueError(f"handover lanes must be >= 0, got {self.lanes}")
        if self.behind_m < 0:
            raise ValueError(f"handover behind_m must be >= 0, got {self.behind_m}")


#: scenarios per chunk: SUMO (one road each in one network; and LLM planners anywhere) and the log replay,
#: whose planners are batched NumPy, faster per scenario in larger batches (``letspi bench closed-loop``)
DEFAULT_CHUNK_SUMO: Final = 32
DEFAULT_CHUNK_REPLAY: Final = 256


@dataclass(frozen=True)
class ClosedLoopConfig:
    """How a closed-loop run simulates (the one closed-loop settings type; module docstring).

    Attributes:
        mode: a closed-loop ``EvaluationMode`` (or its string value).
        replan_s: replanning period [s] of every planner (1.0 default; 5.0 = plan once, i.e.
            open-loop plan in a closed-loop world). Rounded to whole 0.04 s frames.
        planner_replan_s: label -> that planner's own period [s] (e.g. a slower one for an LLM
            planner); ``for_planner(label)`` is the configuration one planner runs under.
        workers: 0 = this process; N = N worker processes (or N Ray actors with ``ray_address``).
        ray_address: run on Ray: ``local`` starts a local instance, else a cluster address.
        chunk_size: scenarios simulated together in one SUMO network or replay (stepped in
            lockstep, replanned in one batched planner call); also the unit of work of the worker
            processes and of resumable output (not part of any key: measured, chunk sizes 3, 32 and
            256 give the same plans to 1e-12 m; the learned goal predictor's last bits depend on the
            batch, and a discrete choice of ``sf-check`` or ``sf-opt`` followed such a bit in about
            one closed-loop window of 2,000). None (default): ``DEFAULT_CHUNK_REPLAY`` for the
            replay, whose planners run faster in larger batches; ``DEFAULT_CHUNK_SUMO`` with SUMO
            (one road per scenario in one network) and for the dual-rate LLM planners, whose
            measured answer latency queues a chunk's scenarios on the model (``scenarios_per_chunk``).
        lateral_resolution_m: SUMO's sublane resolution [m]. The sublane model is needed so that
            SUMO's collision check looks at lateral positions (the exact position, not the grid);
            the resolution only shapes the lane-change model of reactive neighbours.
        road_behind_m, road_ahead_m: the simulated road extends this far behind / ahead of the
            ego's t = 0 position [m].
        slot_spacing_m: lateral distance between the parallel roads of one network [m].
        sumo_backend: ``libsumo`` (in-process, fast; one simulation per process) or ``traci``
            (a SUMO subprocess over a socket; needed for the GUI).
        sumo_gui: run ``sumo-gui`` (sets the traci backend; slow: for debugging a few scenarios).
        simulator: ``sumo``, ``replay`` or ``auto`` (the default: ``replay`` in ``closed-loop-log``
            without the GUI, else ``sumo``). The replay (``letspi.simulation.replay``) runs
            ``closed-loop-log`` in NumPy: its neighbours only replay their log, so SUMO would only
            echo positions; the same trajectories and metrics (tested), without SUMO's own collision
            flag, several times faster. The other modes need SUMO's driver models.
        driver: parameters of reactive neighbours (``closed-loop-reactive`` and ``-hybrid``).
        handover: when ``closed-loop-hybrid`` hands a replayed neighbour to SUMO.
        dual_rate: LLM planners (``dual_rate`` in the planner table): the LLM at t = 0 and
            every ``llm_period_s``, its answers in force after their latency, the physics and the
            shield every ``replan_s`` (``letspi.simulation.dual_rate``); other planners ignore it.
    """

    mode: EvaluationMode = EvaluationMode.LOG
    replan_s: float = DEFAULT_REPLAN_S
    planner_replan_s: Mapping[str, float] = field(default_factory=dict)
    workers: int = 0
    ray_address: str | None = None
    chunk_size: int | None = None
    lateral_resolution_m: float = 1.0
    road_behind_m: float = 1000.0
    road_ahead_m: float = 1500.0
    slot_spacing_m: float = 60.0
    sumo_backend: Literal["libsumo", "traci"] = "libsumo"
    sumo_gui: bool = False
    simulator: Literal["auto", "replay", "sumo"] = "auto"
    driver: DriverModelConfig = field(default_factory=DriverModelConfig)
    handover: HandoverConfig = field(default_factory=HandoverConfig)
    dual_rate: DualRateConfig = field(default_factory=DualRateConfig)

    def __post_init__(self) -> None:
        try:
            mode = EvaluationMode(self.mode)
        except ValueError:
            mode = None
        if mode is None or not mode.closed_loop:
            raise ValueError(unknown("closed-loop mode", self.mode, CLOSED_LOOP_MODES))
        object.__setattr__(self, "mode", mode)
        validate_replan_s(self.replan_s)
        for label, period in self.planner_replan_s.items():
            try:
                validate_replan_s(period)
            except ValueError as exc:
                raise ValueError(f"--replan-s {label}={period}: {exc}") from None
        if self.workers < 0:
            raise ValueError(f"--workers must be >= 0, got {self.workers}")
        if self.sumo_gui:
            object.__setattr__(self, "sumo_backend", "traci")
        if self.chunk_size is not None and self.chunk_size < 1:
            raise ValueError(f"chunk_size must be >= 1, got {self.chunk_size}")
        if self.lateral_resolution_m <= 0:
            raise ValueError(
                "lateral_resolution_m must be > 0 (the sublane model is required for SUMO's lateral collision check)"
            )
        if self.road_behind_m < 300 or self.road_ahead_m < 500:
            raise ValueError("the road must reach at least 300 m behind and 500 m ahead of the ego")
        if self.sumo_backend not in ("libsumo", "traci"):
            raise ValueError(f"sumo_backend must be 'libsumo' or 'traci', got {self.sumo_backend!r}")
        if self.simulator not in ("auto", "replay", "sumo"):
            raise ValueError(f"simulator must be 'auto', 'replay' or 'sumo', got {self.simulator!r}")
        if self.simulator == "replay" and mode is not EvaluationMode.LOG:
            raise ValueError(f"--simulator replay runs closed-loop-log only: {mode.value} needs SUMO to drive "
                             "the neighbours")
        if self.simulator == "replay" and self.sumo_gui:
            raise ValueError("--sumo-gui shows SUMO: use --simulator sumo (or auto)")

    @property
    def replan_frames(self) -> int:
        """Replanning period in frames (>= 1)."""
        return replan_frames(self.replan_s)

    def replan_s_of(self, label: str) -> float:
        """The replanning period of the planner labelled ``label`` [s]."""
        return float(self.planner_replan_s.get(label, self.replan_s))

    def for_planner(self, label: str) -> ClosedLoopConfig:
        """The configuration the planner labelled ``label`` runs under: its own period as ``replan_s``."""
        own = self.replan_s_of(label)
        return self if own == self.replan_s else replace(self, replan_s=own)

    def scenarios_per_chunk(self, dual_rate: bool = False) -> int:
        """``chunk_size``, or the default of the simulator and the planner (``dual_rate``: an LLM planner)."""
        if self.chunk_size is not None:
            return self.chunk_size
        return DEFAULT_CHUNK_SUMO if self.uses_sumo or dual_rate else DEFAULT_CHUNK_REPLAY

    @property
    def uses_sumo(self) -> bool:
        """Whether SUMO simulates (else the log replay, ``simulator`` above)."""
        if self.simulator == "auto":
            return self.mode is not EvaluationMode.LOG or self.sumo_gui
        return self.simulator == "sumo"

    def uses_processes(self) -> bool:
        return self.workers > 0 or self.ray_address is not None


def validate_replan_s(replan_s: float) -> float:
    """``replan_s`` if it is a usable replanning period [s], else ``ValueError``."""
    if not DT_S <= float(replan_s) <= N_FUTURE * DT_S:
        raise ValueError(
            f"replan_s must be between one frame ({DT_S} s) and the horizon ({N_FUTURE * DT_S:g} s), got {replan_s}"
        )
    return float(replan_s)


def replan_frames(replan_s: float) -> int:
    """A replanning period [s] in whole frames (at least 1)."""
    return max(1, round(validate_replan_s(replan_s) / DT_S))
