"""Traffic configuration: presets, overrides, validation; the follower safety computation."""

from __future__ import annotations

import dataclasses

import pytest

from letspi.trafficgen.config import (
    CALM,
    HIGHD,
    STRESS,
    DriverConfig,
    EventConfig,
    LayoutConfig,
    setting_keys,
    traffic_preset,
    with_overrides,
)
from letspi.trafficgen.reactions import required_decel


def test_presets_are_instances_and_ordered_by_criticality() -> None:
    assert traffic_preset("highd") is HIGHD and traffic_preset("calm") is CALM and traffic_preset("stress") is STRESS
    rates = [p.events.hard_brake_per_min + p.events.cut_in_per_min + p.events.truck_pullout_per_min
             for p in (CALM, HIGHD, STRESS)]
    assert rates[0] == 0.0 < rates[1] < rates[2]
    assert not CALM.events.any_enabled and not CALM.drivers.lane_change_perception
    assert STRESS.drivers.assertive_share > HIGHD.drivers.assertive_share
    with pytest.raises(ValueError, match="unknown criticality preset 'wild' \\(available: calm, highd, stress"):
        traffic_preset("wild")


def test_overrides_parse_each_type_and_leave_the_preset_alone() -> None:
    cfg = with_overrides(HIGHD, {"events.cut_in_per_min": "9", "drivers.reaction_time_s": "0.3,1.2",
                                 "drivers.lane_change_perception": "false", "layout.kind": "on_ramp",
                                 "max_attempts": "2"})
    assert cfg.events.cut_in_per_min == 9.0 and cfg.drivers.reaction_time_s == (0.3, 1.2)
    assert cfg.drivers.lane_change_perception is False and cfg.layout.kind == "on_ramp" and cfg.max_attempts == 2
    assert HIGHD.events.cut_in_per_min != 9.0  # frozen preset untouched
    # every key listed is settable with its own current value
    for key in setting_keys():
        obj: object = HIGHD
        for part in key.split("."):
            obj = getattr(obj, part)
        text = ",".join(map(str, obj)) if isinstance(obj, tuple) else str(obj)
        assert with_overrides(HIGHD, {key: text}) == HIGHD, key


@pytest.mark.parametrize(("key", "value", "message"), [
    ("events.cut_in_per_min", "lots", "events.cut_in_per_min: expected float, got 'lots'"),
    ("events.cut_in_per_min", "-1", r"events.cut_in_per_min must be in \[0, 60\]"),
    ("drivers.reaction_time_s", "1.0", r"drivers.reaction_time_s: expected a \(low,high\) pair"),
    ("drivers.reaction_time_s", "1.0,0.2", "drivers.reaction_time_s must be"),
    ("layout.kind", "roundabout", "layout.kind must be one of straight, on_ramp, lane_drop"),
    ("events.nope", "1", "unknown traffic setting 'events.nope'; did you mean events.cut_in_per_min"),
    ("events", "1", "'events' is a group"),
])
def test_override_errors_name_the_key(key: str, value: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        with_overrides(HIGHD, {key: value})


def test_configs_are_frozen() -> None:
    with pytest.raises(dataclasses.FrozenInstanceError):
        HIGHD.events.cut_in_per_min = 9.0  # type: ignore[misc]
    with pytest.raises(ValueError, match="drivers.assertive_share"):
        DriverConfig(assertive_share=1.5)
    with pytest.raises(ValueError, match="events.release_decel_mps2"):
        EventConfig(release_decel_mps2=16.0)
    with pytest.raises(ValueError, match="layout.aux_lane_m"):
        LayoutConfig(aux_lane_m=10.0)


def test_required_decel_hand_computed() -> None:
    # Equal speeds, leader not braking: nothing needed.
    assert required_decel(20.0, 30.0, 30.0, 0.0, 30.0) == 0.0
    # Constant leader, closing 10 m/s over 20 m with a 1 m margin: 10² / (2 * 19) = 2.63 -> grid 2.75.
    assert required_decel(20.0, 30.0, 20.0, 0.0, 20.0) == pytest.approx(2.75)
    # Leader braking 6 m/s² from 30 to 18 m/s, equal speeds, 26 m gap. With follower deceleration a
    # (to 18 m/s) the gap shrinks by 72 / a - 12 m over 12 / a s (leader covers 48 m in 2 s, then 18 m/s):
    # 26 - 1 >= 72/a - 12 for a >= 1.95 -> grid 2.0; without the leader's braking far less.
    assert required_decel(26.0, 30.0, 30.0, 6.0, 18.0) == pytest.approx(2.0)
    # Hopeless: 2 m at 20 m/s closing.
    assert required_decel(2.0, 40.0, 20.0, 0.0, 20.0) > 12.0
