"""What an episode run is: the environment and its configuration, the episode's length, the replanning period, the
dual-rate timing of LLM planners; and who drives (a letspi planner or one of highway-env's own vehicles)."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from typing import Any, Final

from letspi.keyed import key_of
from letspi.simulation.schedule import DualRateConfig

#: highway-env's own vehicles as egos: label -> ego kind (``letspi_interop.highway_env.sim.EGO_KINDS``)
NATIVE_EGOS: Final = {"he-idm": "idm", "he-lane-keeper": "lane-keeper"}
NATIVE_DOCS: Final = {"he-idm": "highway-env's IDMVehicle as the ego (IDM + MOBIL), its desired speed the road's limit",
                      "he-lane-keeper": "highway-env's ControlledVehicle with no action: keeps its lane and its "
                                        "initial speed, no car following"}
#: the packages whose versions join a run's identity
VERSIONED: Final = ("highway-env", "gymnasium")
RUN_MODE: Final = "highway-env"


def installed_versions() -> dict[str, str]:
    """The installed versions of ``VERSIONED`` ("missing" for one that is not installed)."""
    out = {}
    for name in VERSIONED:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "missing"
    return out


def _jsonable(value: Any) -> Any:
    return json.loads(json.dumps(value, sort_keys=True))


@dataclass(frozen=True)
class EnvSettings:
    """One environment and how its episodes run.

    env_id: a ``letspi_interop.highway_env.sim.ENV_IDS`` id; config: its configuration keys over the defaults
    (JSON values; ``policy_frequency`` is set from ``replan_s``); duration_s: the episode ends at the latest
    then (an environment may end it earlier: a crash, merge-v0's ramp passed); replan_s: letspi's planners
    replan (and highway-env's policy steps) every this many seconds, a whole number of simulation frames;
    dual_rate: LLM planners ask their model every ``llm_period_s``, answers in force after ``llm_latency_s``.
    """

    env_id: str
    config: tuple[tuple[str, Any], ...] = ()
    duration_s: float = 30.0
    replan_s: float = 0.2
    dual_rate: DualRateConfig = field(default_factory=lambda: DualRateConfig(llm_period_s=2.5, llm_latency_s=1.5))

    def __post_init__(self) -> None:
        config = dict(self.config)
        if "policy_frequency" in config:
            raise ValueError("policy_frequency is set by replan_s (--replan-s), not in the configuration")
        object.__setattr__(self, "config", tuple(sorted((str(k), _jsonable(v)) for k, v in config.items())))
        if not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise ValueError(f"duration_s must be a positive number of seconds, got {self.duration_s}")
        if not (math.isfinite(self.replan_s) and self.replan_s > 0):
            raise ValueError(f"replan_s must be a positive number of seconds, got {self.replan_s}")
        frames = self.simulation_hz * self.replan_s
        if abs(frames - round(frames)) > 1e-9 or round(frames) < 1:
            raise ValueError(f"replan_s {self.replan_s:g} s is not a whole number of simulation frames at "
                             f"{self.simulation_hz:g} Hz")

    @property
    def simulation_hz(self) -> float:
        return float(dict(self.config).get("simulation_frequency", 15))

    @property
    def frames_per_replan(self) -> int:
        return round(self.simulation_hz * self.replan_s)

    @property
    def max_replans(self) -> int:
        return math.ceil(self.duration_s / self.replan_s - 1e-9)

    def env_config(self) -> dict[str, Any]:
        """The configuration handed to highway-env (``policy_frequency`` from ``replan_s``)."""
        return {**dict(self.config), "policy_frequency": 1.0 / self.replan_s}

    def identity(self) -> dict[str, Any]:
        """What changes an episode: the environment, its configuration, the episode's length and replanning."""
        return {"env_id": self.env_id, "config": dict(self.config), "duration_s": round(self.duration_s, 6),
                "replan_s": round(self.replan_s, 6)}

    @property
    def tag(self) -> str:
        """A short name of the environment and its configuration (scenario ids, recording keys)."""
        return f"{self.env_id}-{key_of(self.identity())[:8]}"


@dataclass(frozen=True)
class NativeEgo:
    """One of highway-env's own vehicles as the ego (``NATIVE_EGOS``), labelled ``name``."""

    name: str
    kind: str

    @classmethod
    def of(cls, label: str, native: str) -> NativeEgo:
        if native not in NATIVE_EGOS:
            raise ValueError(f"unknown highway-env ego {native!r}; one of {', '.join(NATIVE_EGOS)}")
        return cls(label, NATIVE_EGOS[native])

    def record(self) -> dict[str, Any]:
        """``config.json`` of its results: kind and identity (its key)."""
        identity = {"kind": f"highway-env:{self.kind}", "version": 1}
        return {"name": self.name, "kind": identity["kind"], "key": key_of(identity), "identity": identity,
                "config": identity}
