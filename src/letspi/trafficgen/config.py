"""Typed configuration of generated traffic: drivers, scripted events, road layout; presets.

A :class:`TrafficConfig` is everything that shapes the generated traffic besides seed, duration,
lanes and flow. The three presets ``calm``, ``highd`` (default) and ``stress`` are instances of
it; every knob can be changed with :func:`with_overrides` (``"events.hard_brake_per_min=2"``),
which the CLI exposes as ``letspi data generate --set KEY=VALUE``.

Ranges are ``(low, high)`` tuples of uniform draws. Validation happens on construction and names
the offending field.
"""

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
        reaction_time_s: range of the per-driver reaction time [s] (rounded to 0.04 s steps).
            In SUMO it is EIDM's ``treaction`` (its decision interval; SUMO's docs say EIDM must
            not be combined with ``actionStepLength``, which produced collisions and 1,000 m/s²
            spikes when tried), and the time a follower keeps its speed in a scripted event.
            The desired headway ``tau`` is raised to at least the reaction time.
        car_headway_s: (mean, sd) of the desired time headway of cars and vans [s].
        min_headway_s: lower clip of the desired time headway of cars and vans [s].
        assertive_share: share of car drivers with ``lcAssertive`` > 1 (LC2013 divides the gap
            it requires on the target lane by it: tight cut-ins).
        assertive_range: range of ``lcAssertive`` for those drivers.
        impatient_share: share of car drivers who are impatient: desired speed +10 %, headway at
            ``min_headway_s``, eager to overtake (``lcSpeedGain`` x2, ``lcSpeedGainLookahead``
            2 s), reluctant to keep right, uncooperative and assertive. (SUMO's own
            ``lcImpatience`` only exists in the sublane model, about 2x slower.)
        lane_change_perception: followers perceive a vehicle changing into their lane only when
            its centre crosses into the lane (when HighD assigns it the lane) and react after
            their reaction time; SUMO's followers would brake from the first moment of the
            change. Applies to every lane change into the recorded window (natural or
            scripted); see :mod:`letspi.trafficgen.reactions`.
        lc_speed_gain_scale: multiplies every driver's drawn LC2013 ``lcSpeedGain`` (eagerness to
            change lanes for speed; < 1 = fewer overtaking lane changes). 1 keeps the drawn values.
        lc_keep_right_scale: multiplies every driver's drawn ``lcKeepRight`` (eagerness to return
            to the right lane; < 1 = fewer keep-right lane changes).
        epsilon_acc_mps2: EIDM ``epsilonacc``: between two decision points (every reaction time)
            a driver reacts at once only when its desired deceleration grows by more than this
            [m/s²] (SUMO's default 1); larger values make the reaction time apply to sharper
            changes too. A desired deceleration beyond the emergency deceleration always
            triggers an immediate reaction.
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
    """Scripted events injected through libsumo while the simulation runs.

    Rates are events per simulated minute on the whole recorded window (both directions). An
    event is started on a vehicle inside the upstream part of the recorded window, so that it
    and its consequences are recorded.

    Attributes:
        hard_brake_per_min: hard-braking leaders per minute.
        hard_brake_decel_mps2: range of the commanded deceleration [m/s²].
        hard_brake_duration_s: range of the braking duration [s].
        hard_brake_hold_s: range of the time the lower speed is kept before driving on [s].
        hard_brake_min_speed_mps: the leader never brakes below this speed [m/s] (only leaders
            fast enough for the drawn deceleration and duration are chosen).
        hard_brake_max_headway_s: the leader's follower must be within this time gap [s].
        cut_in_per_min: forced cut-ins per minute (a car changes into a short gap in front of a
            faster follower; ``changeLane`` with laneChangeMode 256, which still avoids
            immediate collisions).
        cut_in_gap_m: range of the bumper-to-bumper gap to the new follower at the start of the
            lane change [m].
        cut_in_closing_mps: range of the new follower's speed excess over the cutting car [m/s].
        cut_in_ttc_s: range of the follower's TTC at the moment the changer's centre crosses
            into its lane (2 s into the change), had it kept its speed: how tight the cut-in is.
        truck_pullout_per_min: slow trucks pulling out of the right lane per minute.
        truck_pullout_gap_m: range of the gap to the faster follower on the target lane [m].
        truck_pullout_closing_mps: range of that follower's speed excess over the truck [m/s].
        truck_pullout_ttc_s: as ``cut_in_ttc_s`` for trucks.
        follower_reaction: the follower concerned keeps its speed until it perceives the event
            (at once for a braking leader; when the lane changer's centre crosses into its lane
            for a cut-in, which is also when HighD assigns it the lane) plus its reaction time.
        follower_brake_ratio: after its reaction, the follower of a braking leader brakes with
            this share of the leader's deceleration (drawn per event; drivers rarely match a
            hard-braking leader at once) until it no longer closes in; then SUMO takes over.
        follower_jerk_mps3: how fast that braking builds up [m/s³].
        release_decel_mps2: a held follower is released at once when avoiding contact would
            need more than this constant deceleration (computed from the gap, both speeds and
            the leader's remaining braking), so SUMO's car following (emergency deceleration
            9 m/s²) always has a margin; values above 9 produce rear-end contacts (the contact
            policy then re-simulates). A TTC threshold is not used: with a braking leader the
            same TTC can be harmless or unavoidable.
        release_gap_m: ... or when its gap drops below this [m].
    """

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
    """Road layout. HighD recordings have no ramps: only the main carriageway is recorded.

    Attributes:
        kind: ``straight``; ``on_ramp`` (a one-lane ramp feeds an acceleration lane to the right
            of the main carriageway that ends inside the window); ``lane_drop`` (the carriageway
            has one more lane upstream, the right one ends inside the window).
        aux_lane_m: where the acceleration lane / the ending lane ends, measured from the window
            entry [m]; the acceleration lane is 250 m long, so the default 300 m puts all of it
            but the first 50 m inside the window.
        ramp_share: share of each direction's flow that enters from the ramp (``on_ramp``).
        lc_strategic: LC2013 ``lcStrategic`` of every driver on the non-straight layouts (SUMO's
            default 1 makes drivers on an ending lane leave it far upstream, outside the window).
    """

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
    """Everything that shapes the generated traffic (besides seed, duration, lanes and flow).

    Attributes:
        name: preset it was derived from (informative).
        drivers: per-driver behaviour.
        events: scripted events.
        layout: road layout.
        truck_share: share of trucks in the demand.
        max_attempts: simulations tried (seed, then derived sub-seeds) until one has no contact;
            see :mod:`letspi.trafficgen.generate`.
    """

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
#: Calibrated against highD's published marginals (measured in docs/data.md, "The realistic preset"):
#: vehicles changing lanes near highD's 5 % (the ``highd`` preset: 29 %; 4.1 % and 5.3 % on 10 minutes
#: of seeds 5 and 6) with LC2013's eagerness to overtake and to keep right scaled down and no impatient
#: drivers; few scripted events; trucks 17 % of the demand (highD's recording 01: 17.6 %). Every
#: remaining natural lane change is an overtaking one (to the left): lcSpeedGain sets the share. Less
#: overtaking means longer platoons, so cars' desired headway is 1.1 s (not 1.0 s), which keeps the
#: time-headway marginals of the former preset (lcSpeedGain x0.02, 1.0 s; 7.5-7.7 % changing lanes).
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
    """Parse ``text`` into the type of the field's current value."""
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
    """Return ``config`` with dotted-key overrides applied (``{"events.cut_in_per_min": "3"}``).

    Raises:
        ValueError: unknown key (the message lists the valid ones) or a value of the wrong type
            or out of range (naming the key).
    """
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
    """All dotted keys accepted by :func:`with_overrides`."""
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
