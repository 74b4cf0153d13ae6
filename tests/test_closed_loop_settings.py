"""Closed-loop flags come from one declaration (``letspi.simulation.settings``), as planner flags do."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from letspi.cli.app import app
from letspi.simulation.config import EvaluationMode
from letspi.simulation.settings import CLOSED_LOOP_OPTIONS, closed_loop_config


def test_every_declared_setting_is_a_flag_of_evaluate_under_closed_loop() -> None:
    text = CliRunner().invoke(app, ["evaluate", "--help"], terminal_width=200).output
    panel = text[text.index("Closed loop"):]
    for option in CLOSED_LOOP_OPTIONS:
        assert option.cli_flag in panel, option.cli_flag


def test_values_make_the_config_and_defaults_are_the_declared_ones() -> None:
    config = closed_loop_config(EvaluationMode.HYBRID, {"replan_s": ["0.4", "b=0.2"], "workers": 2, "ray": True,
                                                       "handover_lanes": 1, "llm_period_s": 1.0,
                                                       "llm_latency_s": 0.5, "simulator": "sumo"}, ["a", "b"])
    assert config is not None
    assert config.replan_s == pytest.approx(0.4) and dict(config.planner_replan_s) == {"b": 0.2}
    assert config.workers == 2 and config.ray_address == "local" and config.handover.lanes == 1
    assert config.dual_rate.llm_period_s == 1.0 and config.dual_rate.llm_latency_s == 0.5
    assert config.simulator == "sumo"
    plain = closed_loop_config(EvaluationMode.LOG, {}, ["a"])
    assert plain is not None and plain.workers == 0 and plain.ray_address is None and plain.dual_rate.measured


def test_settings_are_refused_where_they_do_not_apply() -> None:
    assert closed_loop_config(EvaluationMode.OPEN_LOOP, {}, ["a"]) is None
    with pytest.raises(ValueError, match="--workers, --llm-period-s apply to the closed-loop modes only"):
        closed_loop_config(EvaluationMode.OPEN_LOOP, {"workers": 2, "llm_period_s": 1.0}, ["a"])
    with pytest.raises(ValueError, match="--handover-lanes applies to --mode closed-loop-hybrid only"):
        closed_loop_config(EvaluationMode.LOG, {"handover_lanes": 1}, ["a"])
    with pytest.raises(ValueError, match="no planner labelled 'x'"):
        closed_loop_config(EvaluationMode.LOG, {"replan_s": ["x=0.2"]}, ["a"])
    with pytest.raises(ValueError, match="--concurrency applies to open loop"):
        closed_loop_config(EvaluationMode.LOG, {}, ["a"], concurrency=4)
