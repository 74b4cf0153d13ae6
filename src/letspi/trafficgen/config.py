"""Typed configuration of generated traffic (drivers, scripted events, road layout) and its presets.

``with_overrides`` sets any field by dotted key (``--set events.hard_brake_per_min=2``). Ranges are ``(low, high)``
tuples of uniform draws; construction validates and names the offending field."""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Literal

from letspi.suggest import unknown

Layout = Literal["straight", "on_ramp", "lane_drop"]
LAYOUTS: tuple[str, ...] = typing.get_args(Layout)
PRESET_NAMES: tuple[str, ...] = ("calm", "highd", "stress", "realistic")


def _check_range(name: str, value: tuple[float, float], lo: float, hi: float) -> None:
    if len(value) != 2 or not (lo <= value[0] <= value[1] <= hi):
        raise ValueError(f"{name} must be (low, high) with {lo} <= low <= high <= {hi}, got {value}")


def _check_in(name: str, value: float, lo: float, hi: float, unit: str = "") -> None:
    if not lo <= value <= hi:
        raise ValueError(f"{name} must be in [{lo:g}, {hi:g}]{unit}, got {value}")


def _check_share(name: str, value: float) -> None:
    _check_in(name, value, 0.0, 1.0)


@dataclass(frozen=True)
class DriverConfig:
    """Per-driver behaviour drawn for every vehicle.

    Attributes:
        reaction_time_s: range [s], rounded to 0.04 s steps: EIDM's ``treaction`` and how long a follower keeps its
            speed in a scripted event; the desired headway ``tau`` is raised to at least it.
        car_headway_s: (mean, sd) of cars' and vans' desired time headway [s]; ``min_headway_s``: its lower clip [s].
        assertive_share, assertive_range: share of car drivers with ``lcAssertive`` > 1 (LC2013 divides the gap it
            requires by it: tight cut-ins), and its range.
        impatient_share: share of impatient car drivers: desired speed +10 %, headway at ``min_headway_s``, eager to
            overtake (``lcSpeedGain`` x2, lookahead 2 s), reluctant to keep right, uncooperative, assertive.
        lane_change_perception: followers perceive a vehicle changing into their lane only when its centre crosses
            into it and react after their reaction time (every lane change into the window; ``reactions``).
        lc_speed_gain_scale, lc_keep_right_scale: multiply every drawn LC2013 ``lcSpeedGain`` / ``lcKeepRight``
            (< 1: fewer overtaking / keep-right lane changes).
        epsilon_acc_mps2: EIDM ``epsilonacc`` [m/s²]: between decision points a driver reacts at once only when its
            desired deceleration grows by more than this (SUMO's default 1), and always beyond emergency deceleration.
    """

    reaction_time_s: tuple[float, float] = (0.2, 1.0)
    car_headway_s: tuple[float, float] = (1.0, 0.3)
    min_headway_s: float = 0.6
    assertive_share: float = 0.35
    assertive_range: tuple[float, float] = (1.5, 3.0)
    impatient_share: float = 0.1
    lane_change_perception: bool = True
    epsilon_acc_mps2: float = 100.0
    lc_speed_gain_scale: float = 1.0
    lc_keep_right_scale: float = 1.0

    def __post_init__(self) -> None:
        _check_range("drivers.reaction_time_s", self.reaction_time_s, 0.04, 3.0)
        if not (0.0 < self.car_headway_s[0] <= 5.0 and 0.0 <= self.car_headway_s[1] <= 2.0):
            raise ValueError(f"drivers.car_headway_s must be (mean in (0, 5], sd in [0, 2]), got {self.car_headway_s}")
        _check_in("drivers.min_headway_s", self.min_headway_s, 0.3, 3.0)
        _check_share("drivers.assertive_share", self.assertive_share)
        _check_range("drivers.assertive_range", self.assertive_range, 1.0, 20.0)
        _check_share("drivers.impatient_share", self.impatient_share)
        for name in ("lc_speed_gain_scale", "lc_keep_right_scale"):
            _check_in(f"drivers.{name}", getattr(self, name), 0.0, 10.0)
        _check_in("drivers.epsilon_acc_mps2", self.epsilon_acc_mps2, 0.1, 100.0)


@dataclass(frozen=True)
class EventConfig:
    """Scripted events injected through libsumo; rates are per simulated minute on the whole window (both directions),
    ranges drawn per event.

    Attributes:
        hard_brake_*: rate; deceleration [m/s²], duration [s] and hold of the lower speed [s]; the minimum speed the
            leader brakes to [m/s] (only leaders fast enough are chosen); the largest time gap of its follower [s].
        cut_in_*: rate of cars changing into a short gap before a faster follower (``changeLane``, lane-change mode
            256); the gap at the start [m], the follower's speed excess [m/s], and its TTC [s] when the changer's
            centre crosses into its lane (2 s in) had it kept its speed. ``truck_pullout_*``: the same for trucks.
        follower_reaction: the follower keeps its speed until it perceives the event (at once for a braking leader,
            at the crossing for a cut-in) plus its reaction time.
        follower_brake_ratio, follower_jerk_mps3: it then brakes with this share of the braking leader's deceleration,
            built up at this jerk [m/s³], until it no longer closes in; then SUMO takes over.
        release_decel_mps2, release_gap_m: a held follower is released at once when avoiding contact would need more
            than this constant deceleration [m/s²] (leaving SUMO's 9 m/s² emergency deceleration a margin), or when
            its gap drops below this [m]."""

    hard_brake_per_min: float = 3.0
    hard_brake_decel_mps2: tuple[float, float] = (4.0, 8.0)
    hard_brake_duration_s: tuple[float, float] = (1.5, 3.0)
    hard_brake_hold_s: tuple[float, float] = (1.0, 4.0)
    hard_brake_min_speed_mps: float = 12.0
    hard_brake_max_headway_s: float = 1.0
    cut_in_per_min: float = 5.0
    cut_in_gap_m: tuple[float, float] = (8.0, 60.0)
    cut_in_closing_mps: tuple[float, float] = (1.5, 12.0)
    cut_in_ttc_s: tuple[float, float] = (0.5, 4.0)
    truck_pullout_per_min: float = 1.0
    truck_pullout_gap_m: tuple[float, float] = (15.0, 80.0)
    truck_pullout_closing_mps: tuple[float, float] = (4.0, 16.0)
    truck_pullout_ttc_s: tuple[float, float] = (0.8, 4.5)
    follower_reaction: bool = True
    follower_brake_ratio: tuple[float, float] = (0.5, 0.9)
    follower_jerk_mps3: float = 12.0
    release_decel_mps2: float = 6.0
    release_gap_m: float = 4.0

    def __post_init__(self) -> None:
        for name in ("hard_brake_per_min", "cut_in_per_min", "truck_pullout_per_min"):
            _check_in(f"events.{name}", getattr(self, name), 0.0, 60.0, " per minute")
        _check_range("events.hard_brake_decel_mps2", self.hard_brake_decel_mps2, 0.5, 9.0)
        _check_range("events.hard_brake_duration_s", self.hard_brake_duration_s, 0.2, 10.0)
        _check_range("events.hard_brake_hold_s", self.hard_brake_hold_s, 0.0, 20.0)
        _check_range("events.cut_in_gap_m", self.cut_in_gap_m, 0.5, 100.0)
        _check_range("events.cut_in_closing_mps", self.cut_in_closing_mps, 0.0, 30.0)
        _check_range("events.truck_pullout_gap_m", self.truck_pullout_gap_m, 0.5, 200.0)
        _check_range("events.truck_pullout_closing_mps", self.truck_pullout_closing_mps, 0.0, 30.0)
        _check_range("events.cut_in_ttc_s", self.cut_in_ttc_s, 0.1, 30.0)
        _check_range("events.truck_pullout_ttc_s", self.truck_pullout_ttc_s, 0.1, 30.0)
        _check_in("events.hard_brake_min_speed_mps", self.hard_brake_min_speed_mps, 0.0, 40.0)
        _check_in("events.hard_brake_max_headway_s", self.hard_brake_max_headway_s, 0.2, 10.0)
        _check_range("events.follower_brake_ratio", self.follower_brake_ratio, 0.1, 1.5)
        _check_in("events.follower_jerk_mps3", self.follower_jerk_mps3, 1.0, 100.0)
        _check_in("events.release_decel_mps2", self.release_decel_mps2, 1.0, 15.0)
        _check_in("events.release_gap_m", self.release_gap_m, 1.0, 100.0)

    @property
    def any_enabled(self) -> bool:
        return self.hard_brake_per_min > 0 or self.cut_in_per_min > 0 or self.truck_pullout_per_min > 0


@dataclass(frozen=True)
class LayoutConfig:
    """Road layout; only the main carriageway is recorded (HighD has no ramps). ``kind``: ``straight``; ``on_ramp`` (a
    one-lane ramp feeds a 250 m acceleration lane right of the carriageway); ``lane_drop`` (one more lane upstream, the
    right one ends). ``aux_lane_m``: where that lane ends, from the window entry [m]. ``ramp_share``: share of each
    direction's flow entering from the ramp. ``lc_strategic``: every driver's LC2013 ``lcStrategic`` on those layouts
    (SUMO's 1 makes drivers leave an ending lane far upstream)."""

    kind: Layout = "straight"
    aux_lane_m: float = 300.0
    ramp_share: float = 0.15
    lc_strategic: float = 0.2

    def __post_init__(self) -> None:
        if self.kind not in LAYOUTS:
            raise ValueError(f"layout.kind must be one of {', '.join(LAYOUTS)}, got {self.kind!r}")
        _check_in("layout.aux_lane_m", self.aux_lane_m, 50.0, 400.0, " m")
        _check_in("layout.ramp_share", self.ramp_share, 0.0, 0.5)
        _check_in("layout.lc_strategic", self.lc_strategic, 0.01, 10.0)


@dataclass(frozen=True)
class TrafficConfig:
    """Everything that shapes the generated traffic besides seed, duration, lanes and flow; ``name``: its preset
    (informative); ``max_attempts``: simulations tried (the seed, then derived sub-seeds) until one has no contact."""

    name: str = "highd"
    drivers: DriverConfig = field(default_factory=DriverConfig)
    events: EventConfig = field(default_factory=EventConfig)
    layout: LayoutConfig = field(default_factory=LayoutConfig)
    truck_share: float = 0.15
    max_attempts: int = 4

    def __post_init__(self) -> None:
        _check_share("truck_share", self.truck_share)
        _check_in("max_attempts", self.max_attempts, 1, 20)

    def to_dict(self) -> dict[str, object]:
        return dataclasses.asdict(self)


CALM = TrafficConfig(
    name="calm",
    drivers=DriverConfig(reaction_time_s=(0.5, 0.5), assertive_share=0.35, impatient_share=0.0,
                         lane_change_perception=False, epsilon_acc_mps2=1.0),
    events=EventConfig(hard_brake_per_min=0.0, cut_in_per_min=0.0, truck_pullout_per_min=0.0),
)
HIGHD = TrafficConfig(name="highd")
STRESS = TrafficConfig(
    name="stress",
    drivers=DriverConfig(car_headway_s=(0.85, 0.3), assertive_share=0.5, assertive_range=(2.0, 5.0),
                         impatient_share=0.25),
    events=EventConfig(hard_brake_per_min=5.0, cut_in_per_min=7.0, truck_pullout_per_min=2.0,
                       hard_brake_decel_mps2=(5.0, 8.0), hard_brake_max_headway_s=1.2,
                       cut_in_ttc_s=(0.4, 3.0)),
)
#: calibrated against highD's published marginals (docs/data.md, "The realistic preset")
REALISTIC = TrafficConfig(
    name="realistic",
    drivers=DriverConfig(car_headway_s=(1.1, 0.3), impatient_share=0.0, lc_speed_gain_scale=0.008,
                         lc_keep_right_scale=0.05),
    events=EventConfig(hard_brake_per_min=0.6, cut_in_per_min=0.5, truck_pullout_per_min=0.1),
    truck_share=0.17,
)
_PRESETS: Mapping[str, TrafficConfig] = MappingProxyType(
    {"calm": CALM, "highd": HIGHD, "stress": STRESS, "realistic": REALISTIC})


def traffic_preset(name: str) -> TrafficConfig:
    """The preset ``calm``, ``highd``, ``stress`` or ``realistic``."""
    try:
        return _PRESETS[name]
    except KeyError:
        raise ValueError(unknown("criticality preset", name, PRESET_NAMES)) from None


def _parse_value(text: str, current: object, key: str) -> object:
    try:
        if isinstance(current, bool):
            if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError(text)
            return text.lower() in ("true", "1", "yes")
        if isinstance(current, int):
            return int(text)
        if isinstance(current, float):
            return float(text)
        if isinstance(current, tuple):
            parts = [p for p in text.replace("(", "").replace(")", "").split(",") if p.strip()]
            if len(parts) != len(current):
                raise ValueError(text)
            return tuple(float(p) for p in parts)
        return text
    except ValueError:
        kind = "a (low,high) pair" if isinstance(current, tuple) else type(current).__name__
        raise ValueError(f"{key}: expected {kind}, got {text!r}") from None


def with_overrides(config: TrafficConfig, overrides: Mapping[str, str]) -> TrafficConfig:
    """``config`` with dotted-key overrides (``{"events.cut_in_per_min": "3"}``); ValueError naming an unknown key
    (listing the valid ones) or a value of the wrong type or out of range."""
    out = config
    for key, text in overrides.items():
        path = key.strip().split(".")
        out = _replace_path(out, path, text, key)
    return out


def _replace_path(obj: object, path: list[str], text: str, key: str) -> typing.Any:
    assert dataclasses.is_dataclass(obj) and not isinstance(obj, type)
    names = [f.name for f in dataclasses.fields(obj)]
    if path[0] not in names:
        raise ValueError(unknown("traffic setting", key, setting_keys()))
    current = getattr(obj, path[0])
    if len(path) == 1:
        if dataclasses.is_dataclass(current):
            example = f"{key}.{dataclasses.fields(current)[0].name}"
            raise ValueError(f"{key!r} is a group; set one of its fields, e.g. {example}")
        value = _parse_value(text, current, key)
    else:
        value = _replace_path(current, path[1:], text, key)
    return dataclasses.replace(obj, **{path[0]: value})


def setting_keys(config: TrafficConfig | None = None) -> list[str]:
    """All dotted keys ``with_overrides`` accepts."""
    def walk(obj: object, prefix: str) -> list[str]:
        keys: list[str] = []
        for f in dataclasses.fields(obj):  # type: ignore[arg-type]
            value = getattr(obj, f.name)
            if dataclasses.is_dataclass(value):
                keys.extend(walk(value, f"{prefix}{f.name}."))
            else:
                keys.append(prefix + f.name)
        return keys

    return walk(config or HIGHD, "")
