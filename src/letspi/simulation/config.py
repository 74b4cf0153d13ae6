"""Settings of the closed-loop engine (typed, frozen, validated once; SI units in the names). ``EvaluationMode``
names the four modes (docs/evaluation.md); ``ClosedLoopConfig`` refuses ``open-loop``, the harness's."""

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
    """SUMO driver parameters of released neighbours (reactive and hybrid modes): fixed IDM accelerations, standstill
    gap and no imperfection; per vehicle from its history (``letspi.simulation.drivers``) the desired speed (clipped
    to ``desired_speed_bounds_mps``) and time headway (``headway_quantile`` of its gaps to an in-path leader within
    ``max_leader_gap_s``, clipped to ``headway_bounds_s``; else ``default_headway_s``)."""

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
            raise ValueError(f"need 0 < headway_bounds_s[0] <= default_headway_s <= headway_bounds_s[1], "
                             f"got {self.headway_bounds_s}, {self.default_headway_s}")
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
    """When ``closed-loop-hybrid`` hands a log-replayed neighbour to SUMO for good (``letspi.simulation.handover``):
    checked every frame after t = 0, scripted-event actors never; when the lane of its centre is one the ego's box
    covers (or at most ``lanes`` lanes beside those) and its front bumper is at least ``behind_m`` behind the ego's
    rear bumper. ``follow_log_speed``: it is commanded its recorded speed, lowered where SUMO's car following needs
    it, until its log ends; else it drives at its desired speed."""

    lanes: int = 0
    behind_m: float = 0.0
    follow_log_speed: bool = True

    def __post_init__(self) -> None:
        if self.lanes < 0:
            raise ValueError(f"handover lanes must be >= 0, got {self.lanes}")
        if self.behind_m < 0:
            raise ValueError(f"handover behind_m must be >= 0, got {self.behind_m}")


#: scenarios per chunk: SUMO (and LLM planners anywhere) and the log replay (batched NumPy: larger batches are faster)
DEFAULT_CHUNK_SUMO: Final = 32
DEFAULT_CHUNK_REPLAY: Final = 256


@dataclass(frozen=True)
class ClosedLoopConfig:
    """How a closed-loop run simulates.

    Attributes:
        mode: a closed-loop ``EvaluationMode`` (or its string value).
        replan_s: replanning period [s] of every planner, rounded to whole 0.04 s frames (5.0: plan once).
        planner_replan_s: label -> that planner's own period [s]; ``for_planner(label)`` applies it.
        workers: 0 = this process; N = N worker processes (or N Ray actors with ``ray_address``).
        ray_address: run on Ray: ``local`` starts a local instance, else a cluster address.
        chunk_size: scenarios simulated together (lockstep, one batched planner call per replan; the unit of
            work and of resumable output; in no key). None: ``scenarios_per_chunk``'s default.
        lateral_resolution_m: SUMO's sublane resolution [m] (shapes only reactive neighbours' lane changes).
        road_behind_m, road_ahead_m: the simulated road behind / ahead of the ego's t = 0 position [m].
        slot_spacing_m: lateral distance between the parallel roads of one network [m].
        sumo_backend: ``libsumo`` (in-process, one simulation per process) or ``traci`` (a subprocess).
        sumo_gui: run ``sumo-gui`` (implies ``traci``). simulator: ``sumo``, ``replay`` (``closed-loop-log``
            in NumPy: no SUMO collision flag) or ``auto`` (``replay`` for ``closed-loop-log`` without the GUI).
        driver, handover, dual_rate: SUMO's driver model, the hybrid hand-over, the LLM planners' timing."""

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
            raise ValueError("lateral_resolution_m must be > 0 (the sublane model is required for SUMO's lateral "
                             "collision check)")
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
        """``chunk_size``, else ``DEFAULT_CHUNK_SUMO`` with SUMO or a dual-rate LLM planner, else the replay's."""
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
        raise ValueError(f"replan_s must be between one frame ({DT_S} s) and the horizon ({N_FUTURE * DT_S:g} s), "
                         f"got {replan_s}")
    return float(replan_s)


def replan_frames(replan_s: float) -> int:
    """A replanning period [s] in whole frames (at least 1)."""
    return max(1, round(validate_replan_s(replan_s) / DT_S))
