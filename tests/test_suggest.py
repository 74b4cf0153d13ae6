"""A mistyped name gets the closest known ones ("did you mean"): planner kinds, suites, modes, option values."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from letspi.assembly.planners import resolve_planner
from letspi.benchmark.run import selected_modes
from letspi.benchmark.suites import get_suite
from letspi.cli.app import app
from letspi.planners.options import PlannerOptions
from letspi.simulation.config import EvaluationMode
from letspi.suggest import did_you_mean, unknown


def test_the_closest_names_or_nothing() -> None:
    assert did_you_mean("sff", ["human", "sf", "sf-opt", "cv"]) == "; did you mean sf?"  # sf-opt: ratio 0.44
    assert did_you_mean("closed-loop-logg", ["open-loop", "closed-loop-log", "closed-loop-hybrid"]) == (
        "; did you mean closed-loop-log or closed-loop-hybrid?")
    assert did_you_mean("zzz", ["human", "sf"]) == ""
    assert unknown("goal source", "learnd", ("learned", "kinematic")) == (
        "unknown goal source 'learnd'; did you mean learned? (available: learned, kinematic)")


def test_suites_modes_and_option_values_suggest_the_closest() -> None:
    with pytest.raises(ValueError, match="unknown benchmark suite 'highway-critcal'; did you mean highway-critical"):
        get_suite("highway-critcal")
    with pytest.raises(ValueError, match="unknown evaluation mode 'closed-loop-logg'; did you mean closed-loop-log"):
        EvaluationMode("closed-loop-logg")
    with pytest.raises(ValueError, match="has no mode open-lop; did you mean open-loop\\?"):
        selected_modes(get_suite("highway-critical"), ["open-lop"])
    with pytest.raises(ValueError, match="unknown goal source 'learnd'; did you mean learned\\?"):
        resolve_planner("sf", PlannerOptions(goals="learnd"))
    with pytest.raises(ValueError, match="unknown neighbour prediction 'idmm'; did you mean idm\\?"):
        resolve_planner("sf", PlannerOptions(neighbour_mode="idmm"))


def test_the_command_line_names_the_closest_mode_and_planner(tmp_path) -> None:
    runner = CliRunner()
    result = runner.invoke(app, ["evaluate", "--scenarios", "x.arrow", "--planner", "sf", "--out", str(tmp_path / "o"),
                                 "--mode", "closed-loop-logg"])
    assert result.exit_code == 2 and "did you mean closed-loop-log" in result.output
    result = runner.invoke(app, ["evaluate", "--scenarios", "x.arrow", "--planner", "sff", "--out",
                                 str(tmp_path / "o")])
    assert result.exit_code == 2 and "unknown planner 'sff'; did you mean sf?" in " ".join(result.output.split())
