"""Planner options: declared beside each planner, reachable from every command that takes planners, and a new
kind with a setting needs nothing in ``letspi.cli``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import pytest
import typer
from typer.testing import CliRunner

from benchmarks.speed import app as speed_app
from letspi.assembly.planner_table import BUILT_IN, FutureUse, PlannerKind, PlannerTable
from letspi.assembly.planners import build_planners, resolve_planner
from letspi.cli.app import app
from letspi.cli.options import planner_options
from letspi.keyed import Config
from letspi.llm.compact import PROMPT_STYLES
from letspi.planners.config import GOAL_SOURCES
from letspi.planners.cv import ConstantVelocityPlanner
from letspi.planners.frenet import FrenetWeights, save_frenet_weights
from letspi.planners.options import PlannerOption, PlannerOptions, unique_options
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.store import save_scenarios
from letspi.scenario.types import concat_batches

runner = CliRunner()
#: the commands that take planners (their planner flags come from the table)
PLANNER_COMMANDS = (["evaluate"], ["plan"], ["plot"], ["speed", "closed-loop"], ["benchmark", "run"])


def _help(*command: str) -> str:
    """``letspi COMMAND --help``, or ``python -m benchmarks.speed COMMAND --help`` for ``("speed", COMMAND)``."""
    cli, args = (speed_app, command[1:]) if command[0] == "speed" else (app, command)
    result = runner.invoke(cli, [*args, "--help"], terminal_width=400)
    assert result.exit_code == 0, result.output
    return result.output


@pytest.mark.parametrize("command", PLANNER_COMMANDS, ids=" ".join)
def test_every_setting_of_every_kind_is_a_flag_of_every_command_that_takes_planners(command: list[str]) -> None:
    text = _help(*command)
    missing = [o.cli_flag for o in BUILT_IN.options() if o.cli_flag not in text]
    exempt = {"--cache"} if command == ["speed", "closed-loop"] else set()  # the bench times LLMs uncached
    assert set(missing) == exempt, missing


def test_the_commands_of_one_part_offer_exactly_its_settings() -> None:
    collect = _help("collect")
    assert "--max-iterations" in collect and "--prompt-style" in collect and "--sf-params" in collect
    assert "--top-k" not in collect and "--shield" not in collect  # not settings of memory collection
    robustness = _help("speed", "robustness")
    assert "--mlp-weights" in robustness and "--frenet-weights" in robustness and "--llm " not in robustness
    ablate = _help("ablate")
    assert "--memory-fraction" in ablate and "--frenet-weights" not in ablate


def test_each_flag_carries_its_declared_default_unit_and_choices() -> None:
    text = " ".join(_help("evaluate").split())
    assert "[s] [default: 120.0]" in text  # --request-timeout: unit and default from LLM_TIMEOUT
    assert f"({', '.join(PROMPT_STYLES)})" in text and f"({', '.join(GOAL_SOURCES)})" in text and "mobil" in text
    assert "--shield / --no-shield" in text and "--cache / --no-cache" in text


def _scenarios(tmp_path: Path) -> Path:
    batch = concat_batches([straight_road_scenario(scenario_id=f"s{i}", neighbours=[VehicleSpec(30.0, 24.0)])
                            for i in range(2)])
    return save_scenarios(batch, tmp_path / "s.arrow")


def test_frenet_weights_and_the_prompt_style_reach_the_configuration(tmp_path: Path) -> None:
    """The two settings no command could reach before the options came from the table."""
    weights = save_frenet_weights(tmp_path / "w.json", FrenetWeights(k_goal_lane=3.0), {}, {})
    out = tmp_path / "ev"
    result = runner.invoke(app, ["evaluate", "--scenarios", str(_scenarios(tmp_path)), "--planner", "frenet",
                                 "--planner", "shipped=frenet", "--goals", "kinematic", "--frenet-weights",
                                 str(weights), "--out", str(out)])
    assert result.exit_code == 0, result.output
    record = json.loads((out / "per_scenario" / "frenet" / "config.json").read_text())
    assert record["config"]["weights_source"] == str(weights)
    assert record["config"]["frenet"]["weights"]["k_goal_lane"] == 3.0
    shipped = resolve_planner("frenet", PlannerOptions(goals="kinematic"))
    assert record["key"] != shipped.key()
    compact = resolve_planner("llm", PlannerOptions(llm="scripted:default", prompt_style="compact"))
    assert compact.phase.llm.prompt_style == "compact"  # type: ignore[attr-defined]
    result = runner.invoke(app, ["plan", "--scenarios", str(_scenarios(tmp_path)), "--index", "0", "--planner",
                                 "llm", "--llm", "scripted:default", "--prompt-style", "chatty", "--no-cache"])
    assert result.exit_code == 2 and "unknown prompt style 'chatty' (available: paper, compact" in result.output


def test_a_switch_without_a_default_is_three_valued(tmp_path: Path) -> None:
    """--decide / --no-decide / neither (None: the kind's default): sf-check is the decision step, so it
    refuses --no-decide in one line."""
    base = ["plan", "--scenarios", str(_scenarios(tmp_path)), "--index", "0", "--planner", "sf-check", "--goals",
            "kinematic", "--json"]
    assert runner.invoke(app, base).exit_code == 0
    assert runner.invoke(app, [*base, "--decide"]).exit_code == 0
    refused = runner.invoke(app, [*base, "--no-decide"])
    assert refused.exit_code == 2 and "sf-check is the decision step without a model" in refused.output


def test_a_misspelt_option_is_an_error_naming_it() -> None:
    with pytest.raises(ValueError, match=r"unknown planner option\(s\) goal; did you mean goals\? \(available: "):
        build_planners(["sf"], PlannerOptions(goal="kinematic"))
    with pytest.raises(ValueError, match="unknown planner option"):
        resolve_planner("cv", PlannerOptions(neighbours="idm"))


def test_options_are_given_by_the_flags_words_or_their_names() -> None:
    declared = BUILT_IN.options()
    by_flag = PlannerOptions.from_keywords(declared, neighbours="constant_velocity", sf_params="p.json", cache=False,
                                           request_timeout=5.0, presets="x.json", risk_model="r.json")
    assert by_flag == PlannerOptions(neighbour_mode="constant_velocity", sf_params_file="p.json", llm_cache=False,
                                     llm_timeout_s=5.0, presets_file="x.json", risk_model_file="r.json")
    assert PlannerOptions.from_keywords(declared, neighbour_mode="idm") == PlannerOptions(neighbour_mode="idm")
    with pytest.raises(ValueError, match="neighbours= and neighbour_mode= are one option \\(--neighbours\\)"):
        PlannerOptions.from_keywords(declared, neighbours="idm", neighbour_mode="idm")
    with pytest.raises(ValueError, match="unknown planner option neighbors='idm'; did you mean neighbours"):
        PlannerOptions.from_keywords(declared, neighbors="idm")


def test_options_are_values_with_declared_defaults() -> None:
    option = PlannerOption("top_k", int, 3, "memories")
    options = PlannerOptions(goals="kinematic")
    assert options.get(option) == 3 and options.replace(top_k=5).get(option) == 5 and options.get(option) == 3
    assert options == PlannerOptions(goals="kinematic") and options != PlannerOptions()
    with pytest.raises(AttributeError):
        options.top_k = 5  # type: ignore[attr-defined]
    with pytest.raises(ValueError, match="declared twice"):
        unique_options([[option], [PlannerOption("top_k", int, 5, "memories")]])
    with pytest.raises(ValueError, match="identifier"):
        PlannerOption("top-k", int, 3, "memories")


# a planner kind from outside letspi: a module, its configuration, its option; no edit in letspi.cli
class SlowConfig(Config):
    kind: str = "slow-cv"
    slowdown: float


SLOWDOWN = PlannerOption("slowdown", float, 1.0, "Divide the speed by this", unit="1")
SLOW = PlannerKind("slow-cv", "constant velocity, slower", SlowConfig,
                   lambda r: SlowConfig(slowdown=r.options.get(SLOWDOWN)),
                   lambda b, c, label: (ConstantVelocityPlanner(name=label), 0.0), (SLOWDOWN,),
                   future=FutureUse.NEVER)


def test_a_new_kind_brings_its_setting_to_the_command_line_through_the_table() -> None:
    table = BUILT_IN.with_kinds(SLOW)
    seen: dict[str, Any] = {}
    cli = typer.Typer()

    @cli.command()
    @planner_options(declared=table.options(["slow-cv", "sf"]))
    def run(options: PlannerOptions,
            planner: Annotated[str, typer.Option()] = "slow-cv") -> None:
        seen["config"] = resolve_planner(planner, options, table=table)

    result = runner.invoke(cli, ["--slowdown", "2.5", "--goals", "kinematic"])
    assert result.exit_code == 0, result.output
    assert seen["config"] == SlowConfig(slowdown=2.5)
    assert "Divide the speed by this [1]" in runner.invoke(cli, ["--help"]).output
    built = build_planners(["slow-cv"], PlannerOptions(slowdown=2.0), table=table)[0]
    assert not built.reads_future and not built.dual_rate and built.config.key() != SlowConfig(slowdown=1.0).key()
    with pytest.raises(ValueError, match="unknown planner option"):
        build_planners(["sf"], PlannerOptions(slowdown=2.0))  # the built-in table has no such setting
    with pytest.raises(ValueError, match="given twice"):
        PlannerTable((*BUILT_IN.kinds, BUILT_IN.kind("sf")))


def test_letspi_planners_lists_each_kinds_settings() -> None:
    rows = {row["kind"]: row for row in json.loads(runner.invoke(app, ["planners", "--json"]).output)}
    assert [o["flag"] for o in rows["frenet"]["options"]] == ["--neighbours", "--goals", "--goal-weights",
                                                              "--frenet-weights"]
    assert rows["letspi-fast"]["dual_rate"] and not rows["sf"]["dual_rate"]
    assert rows["cv"]["options"] == [] and rows["human"]["options"] == []
