"""The benchmark suites: one table (``SUITES``), one entry per suite pinning everything that makes a result
(docs/benchmark.md). The id ``NAME@vVERSION-DIGEST8`` hashes ``Suite.definition`` (``tests/test_benchmark.py`` pins
every id). Suites of other simulators join through the ``letspi.suites`` entry-point group (``ExternalSuite``;
letspi-interop adds highway-env's)."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cache
from importlib.metadata import entry_points
from pathlib import Path
from types import MappingProxyType
from typing import Any, Final, Protocol

from letspi.constants import DEFAULT_STRIDE_FRAMES
from letspi.metrics.config import MetricsConfig
from letspi.planners.options import PlannerOptions
from letspi.scenario.provenance import SUITE_SEEDS
from letspi.suggest import unknown
from letspi.trafficgen.config import LAYOUTS, TrafficConfig, traffic_preset, with_overrides

#: evaluation modes a suite may use (the harness' names)
SUITE_MODES: Final = ("open-loop", "closed-loop-log")
#: the planner every other is compared with, paired
REFERENCE_PLANNER: Final = "sf"


@dataclass(frozen=True)
class GeneratedTraffic:
    """Traffic of letspi's SUMO generator, one run per seed (in ``SUITE_SEEDS``) cut into recordings: preset
    (``--criticality``), overrides (``--set KEY=VALUE``), layout, seeds, minutes and recording_minutes,
    lanes_per_direction, flow_veh_per_h (None: the generator's default)."""

    preset: str
    layout: str
    seeds: tuple[int, ...]
    minutes: float
    recording_minutes: float = 10.0
    overrides: tuple[tuple[str, str], ...] = ()
    lanes_per_direction: int = 3
    flow_veh_per_h: float | None = None

    def __post_init__(self) -> None:
        if self.layout not in LAYOUTS:
            raise ValueError(f"layout must be one of {', '.join(LAYOUTS)}, got {self.layout!r}")
        outside = [s for s in self.seeds if s not in SUITE_SEEDS]
        if outside or not self.seeds or len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"suite seeds must be distinct and in {SUITE_SEEDS.start}-{SUITE_SEEDS.stop - 1}, "
                             f"got {self.seeds}")

    def traffic_config(self) -> TrafficConfig:
        """The full traffic configuration (the preset, its layout and overrides applied)."""
        return with_overrides(traffic_preset(self.preset), {"layout.kind": self.layout, **dict(self.overrides)})

    def definition(self) -> dict[str, Any]:
        return {"source": "generated", "preset": self.preset, "overrides": [list(o) for o in self.overrides],
                "seeds": list(self.seeds), "minutes": self.minutes, "recording_minutes": self.recording_minutes,
                "lanes_per_direction": self.lanes_per_direction, "flow_veh_per_h": self.flow_veh_per_h,
                "traffic": self.traffic_config().to_dict()}


@dataclass(frozen=True)
class RealHighD:
    """Real HighD recordings from the user's licensed copy, by id. ``file_digests``: id -> SHA-256 (16 hex digits) of
    its three CSV files; other files are refused (``--allow-other-files``: warned). Empty: not pinned yet."""

    recording_ids: tuple[int, ...]
    file_digests: Mapping[int, str] = field(default_factory=dict)

    def definition(self) -> dict[str, Any]:
        return {"source": "highd", "recording_ids": list(self.recording_ids),
                "file_digests": {str(k): v for k, v in sorted(self.file_digests.items())}}


@dataclass(frozen=True)
class Extraction:
    """How windows are cut (``letspi data scenarios``): focus uniform or critical (``critical_share`` of the
    windows drawn from those with a conflict of the ego in their recorded future), ``n_windows`` sampled
    by ``seed``."""

    focus: str
    n_windows: int
    seed: int
    critical_share: float = 0.0
    stride_frames: int = DEFAULT_STRIDE_FRAMES

    def __post_init__(self) -> None:
        if self.focus not in ("uniform", "critical"):
            raise ValueError(f"focus must be uniform or critical, got {self.focus!r}")
        if (self.focus == "critical") != (self.critical_share > 0):
            raise ValueError("critical_share > 0 exactly with focus critical")

    def definition(self) -> dict[str, Any]:
        return {"focus": self.focus, "n_windows": self.n_windows, "seed": self.seed,
                "critical_share": self.critical_share, "stride_frames": self.stride_frames}


@dataclass(frozen=True)
class Mode:
    """One evaluation mode of a suite: closed loop replans every ``replan_s``; LLM planners ask every
    ``llm_period_s`` with a fixed answer latency ``llm_latency_s``; ``n_windows``: a random subset (extraction seed;
    None: all)."""

    mode: str
    replan_s: float | None = None
    llm_period_s: float | None = None
    llm_latency_s: float | None = None
    n_windows: int | None = None

    def __post_init__(self) -> None:
        if self.mode not in SUITE_MODES:
            raise ValueError(f"mode must be one of {', '.join(SUITE_MODES)}, got {self.mode!r}")
        closed = self.mode != "open-loop"
        if closed != (self.replan_s is not None) or closed != (self.llm_period_s is not None):
            raise ValueError("replan_s and llm_period_s are given exactly for the closed-loop modes")

    @property
    def slug(self) -> str:
        """Directory name of the mode's results."""
        return self.mode if self.replan_s is None else f"{self.mode}-{self.replan_s:g}s"

    def definition(self) -> dict[str, Any]:
        return {"mode": self.mode, "replan_s": self.replan_s, "llm_period_s": self.llm_period_s,
                "llm_latency_s": self.llm_latency_s, "n_windows": self.n_windows}


OPEN_LOOP: Final = Mode("open-loop")
#: the suites' closed loop: physics replans every 0.2 s, the LLM is asked every 2.5 s; 2,000 of the windows
CLOSED_LOOP_DUAL_RATE: Final = Mode("closed-loop-log", replan_s=0.2, llm_period_s=2.5, llm_latency_s=1.5,
                                    n_windows=2000)


class Pinned:
    """The id of a suite from its ``definition()``: ``NAME@vVERSION-DIGEST8`` (letspi's suites and companions')."""

    name: str
    version: int

    def definition(self) -> dict[str, Any]:
        raise NotImplementedError

    @property
    def digest(self) -> str:
        return definition_digest(self.definition())

    @property
    def suite_id(self) -> str:
        return f"{self.name}@v{self.version}-{self.digest}"


@dataclass(frozen=True)
class Suite(Pinned):
    """One benchmark suite. ``scripted``: what the reader must know about the events
    in the traffic (scripted or not, and how many), shown by ``list``/``show`` and in the leaderboard."""

    name: str
    version: int
    description: str
    data: GeneratedTraffic | RealHighD
    extraction: Extraction
    modes: tuple[Mode, ...]
    scripted: str
    sizing: str
    metrics: MetricsConfig = field(default_factory=MetricsConfig)

    def definition(self) -> dict[str, Any]:
        """Everything that makes a result of this suite (what the digest is computed over)."""
        return {"name": self.name, "version": self.version, "data": self.data.definition(),
                "extraction": self.extraction.definition(), "modes": [m.definition() for m in self.modes],
                "metrics": self.metrics.recorded(), "reference": REFERENCE_PLANNER}

    @property
    def generated(self) -> bool:
        return isinstance(self.data, GeneratedTraffic)


def definition_digest(definition: Mapping[str, Any]) -> str:
    """The first 8 hex digits of the BLAKE2b hash of a definition's canonical JSON."""
    text = json.dumps(definition, sort_keys=True, separators=(",", ":"))
    return hashlib.blake2b(text.encode("utf-8"), digest_size=16).hexdigest()[:8]


_CRITICAL_SIZING = ("closed loop, 2,000 windows: planners disagree on 0.7-1.7 % of them, a 1-point CR difference "
                    "is detected by exact McNemar (alpha 0.05) with power 0.77-0.99; open loop, 3,000 windows: "
                    "frenet vs sf disagree on 2.8-4.3 % (design effect 1.3-1.5), power 0.61-0.75, 4,600 would "
                    "reach 0.8 (docs/benchmark.md); the decision step's evaluation needs >= 2,000 critical windows in "
                    "both modes")


def _critical(name: str, description: str, preset: str, layout: str, seed: int, scripted: str,
              modes: tuple[Mode, ...] = (OPEN_LOOP, CLOSED_LOOP_DUAL_RATE)) -> Suite:
    """A critical-focus suite (version 1): 20 minutes of traffic of generator seeds ``seed`` and ``seed + 1``,
    3,000 windows drawn with ``seed``, half of them with a conflict of the ego."""
    return Suite(name=name, version=1, description=description,
                 data=GeneratedTraffic(preset=preset, layout=layout, seeds=(seed, seed + 1), minutes=20.0),
                 extraction=Extraction(focus="critical", n_windows=3000, seed=seed, critical_share=0.5),
                 modes=modes, scripted=scripted, sizing=_CRITICAL_SIZING)


#: THE table of suites (one entry per suite; seeds are never shared between suites)
SUITES: Final[Mapping[str, Suite]] = MappingProxyType({s.name: s for s in (
    Suite(
        name="highway-uniform", version=2,
        description="straight 3+3-lane highway, realistic traffic, windows drawn uniformly (the paper's protocol)",
        data=GeneratedTraffic(preset="realistic", layout="straight", seeds=(1001, 1002), minutes=20.0),
        extraction=Extraction(focus="uniform", n_windows=3000, seed=1001),
        modes=(OPEN_LOOP,),
        scripted="scripted events, few: 22 hard brakes, 13 cut-ins, 3 truck pull-outs in the 40 minutes; 309 of "
                 "25,613 windows have a conflict",
        sizing="3,000 windows: open-loop CRs here are 0.2-0.7 % and planners disagree on at most 0.4 % of "
               "the windows, so a 1-point difference is detected with power 1.00 (docs/benchmark.md)",
    ),
    _critical("highway-critical",
              "straight highway, the default (highd) traffic, half the windows with a conflict of the ego",
              "highd", "straight", 1011,
              "scripted events: 107 hard brakes, 115 cut-ins, 24 truck pull-outs in the 40 minutes", (OPEN_LOOP,)),
    _critical("stress-closed-loop",
              "straight highway, stress traffic, critical windows, open loop and closed-loop-log "
              "(replanning every 0.2 s; LLM planners dual-rate: the model every 2.5 s, 1.5 s latency)",
              "stress", "straight", 1021,
              "scripted events: 179 hard brakes, 82 cut-ins, 45 truck pull-outs in the 40 minutes"),
    _critical("on-ramp-critical",
              "on-ramp (acceleration lane ending in the window), default traffic, critical windows, "
              "open loop and closed-loop-log (0.2 s; dual-rate LLM 2.5 s)",
              "highd", "on_ramp", 1031,
              "scripted events: 98 hard brakes, 116 cut-ins, 30 truck pull-outs in the 40 minutes; merges from "
              "the ramp are not scripted"),
    _critical("lane-drop-critical",
              "lane drop (the right lane ends in the window), default traffic, critical windows, "
              "open loop and closed-loop-log (0.2 s; dual-rate LLM 2.5 s)",
              "highd", "lane_drop", 1041,
              "scripted events: 88 hard brakes, 110 cut-ins, 25 truck pull-outs in the 40 minutes; merges where "
              "the lane ends are not scripted"),
    Suite(
        name="highd-real", version=1,
        description="your licensed HighD copy: 6 recordings spread over the 60 (ids 1, 7, 13, 25, 45, 60), "
                    "windows drawn uniformly; give the directory with --highd",
        data=RealHighD(recording_ids=(1, 7, 13, 25, 45, 60)),
        extraction=Extraction(focus="uniform", n_windows=3000, seed=1051),
        modes=(OPEN_LOOP,),
        scripted="real traffic: nothing is scripted",
        sizing="3,000 windows, as highway-uniform",
    ),
)})


def get_suite(name: str) -> Suite:
    """The suite called ``name`` (its bare name, or its full id, whose digest must match)."""
    bare = name.split("@", 1)[0]
    suite = SUITES.get(bare)
    if suite is None:
        raise ValueError(unknown("benchmark suite", name, SUITES))
    if "@" in name and name != suite.suite_id:
        raise ValueError(f"{name} is not this letspi's {bare}: its definition is {suite.suite_id} "
                         "(another version or digest; results of the two are not comparable)")
    return suite


# Suites of other simulators (companion distributions)

#: the entry-point group through which other distributions add suites: each entry point names a
#: ``Mapping[str, ExternalSuite]`` (e.g. ``letspi_interop.highway_env.suite:SUITES``)
SUITES_GROUP: Final = "letspi.suites"


class ExternalSuite(Protocol):
    """A suite another simulator runs: what ``letspi benchmark list``, ``show`` and ``run`` ask of it."""

    name: str

    @property
    def suite_id(self) -> str: ...

    def definition(self) -> dict[str, Any]: ...

    def list_lines(self) -> list[str]:
        """Its entry in ``letspi benchmark list`` (the id first)."""
        ...

    def show_lines(self) -> list[str]:
        """What ``letspi benchmark show`` prints."""
        ...

    def run(self, planners: Sequence[str] | None, out: Path, *, options: PlannerOptions, workers: int,
            reports: bool, progress: Callable[[str, int], Callable[[int], None]],
            log: Callable[[str], None]) -> str:
        """Every planner (None: the suite's defaults) into ``out`` (resumable); returns the table to print."""
        ...


@cache
def external_suites() -> Mapping[str, ExternalSuite]:
    """The suites of installed companion distributions, by name."""
    found: dict[str, ExternalSuite] = {}
    for ep in sorted(entry_points(group=SUITES_GROUP), key=lambda e: e.name):
        for name, suite in ep.load().items():
            if name in SUITES or name in found:
                raise ValueError(f"entry point {ep.value} ({SUITES_GROUP}) redefines the suite {name!r}")
            found[name] = suite
    return MappingProxyType(found)


def get_any_suite(name: str) -> Suite | ExternalSuite:
    """The suite called ``name``, letspi's or a companion's (its bare name, or its full id, whose digest must
    match)."""
    bare = name.split("@", 1)[0]
    suite = external_suites().get(bare)
    if suite is None:
        if bare not in SUITES:
            raise ValueError(f"unknown benchmark suite {name!r}; available: "
                             f"{', '.join([*SUITES, *external_suites()])}")
        return get_suite(name)
    if "@" in name and name != suite.suite_id:
        raise ValueError(f"{name} is not this letspi's {bare}: its definition is {suite.suite_id} "
                         "(another version or digest; results of the two are not comparable)")
    return suite
