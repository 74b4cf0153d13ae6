"""The choice prompt (``letspi.llm.choice``): rendering, reply schema and parsing."""

from __future__ import annotations

import numpy as np
import pytest

from letspi.llm.choice import OptionLine, choice_json_schema, choice_reply_text, parse_choice, render_choice_prompt
from letspi.llm.describe import describe_scenario
from letspi.llm.types import ReplyParseError
from letspi.scenario.build import VehicleSpec, straight_road_scenario

LINES = [OptionLine("default", ("leader-brakes",), 141.2), OptionLine("keep-gap", (), 131.0),
         OptionLine("lane-left", ("predicted", "cut-in"), float("nan"))]


def _desc():  # type: ignore[no-untyped-def]
    batch = straight_road_scenario(neighbours=[VehicleSpec(25.0, 27.0)])
    return describe_scenario(batch.history(), np.array([140.0, 0.0]))


def test_the_prompt_lists_each_option_with_its_failed_checks_and_progress() -> None:
    system, user = render_choice_prompt(_desc(), LINES)
    assert "leader-brakes" in system["content"] and '{"option": name}' in system["content"]
    text = user["content"]
    assert "default: leader-brakes; 141 m" in text and "keep-gap: none; 131 m" in text
    assert "lane-left: predicted, cut-in; - m" in text and "Rejected" not in text
    _, refine = render_choice_prompt(_desc(), LINES, rejected="default", report="failed leader-brakes")
    assert refine["content"].endswith("Rejected: default\nCheck: failed leader-brakes")
    with pytest.raises(ValueError, match="both"):
        render_choice_prompt(_desc(), LINES, rejected="default")


def test_replies_are_one_of_the_names() -> None:
    names = ["default", "keep-gap"]
    assert choice_json_schema(names)["properties"]["option"]["enum"] == names
    assert parse_choice(choice_reply_text("keep-gap"), names) == "keep-gap"
    assert parse_choice('sure: {"option": "default"}', names) == "default"
    for bad, reason in (('{"option": "brake"}', "bad_value"), ('{"choice": "default"}', "missing_keys"),
                        ("default", "no_json"), ('{"option": 2}', "bad_value")):
        with pytest.raises(ReplyParseError) as err:
            parse_choice(bad, names)
        assert err.value.reason == reason
