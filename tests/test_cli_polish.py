"""First-run polish (issue 15): version, help texts, number formats, JSON fields."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from typing import Any

import typer
from typer.testing import CliRunner

from benchmarks.speed import format_number
from letspi.cli.app import app
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.store import save_scenarios

runner = CliRunner()


def _commands(group: Any, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    out = []
    for name, cmd in group.commands.items():
        out.append((*prefix, name))
        if hasattr(cmd, "commands"):  # a group (typer may bring its own click classes)
            out += _commands(cmd, (*prefix, name))
    return out


def test_version() -> None:
    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0 and result.output.startswith("letspi ")


def test_help_texts_show_no_bool_type_and_keep_brackets() -> None:
    commands = _commands(typer.main.get_command(app))
    assert ("benchmark", "run") in commands
    assert (("train", "goals") in commands) == (importlib.util.find_spec("letspi_train") is not None)
    for path in [(), *commands]:
        result = runner.invoke(app, [*path, "--help"])
        assert result.exit_code == 0, (path, result.output)
        assert "<bool>" not in result.output, path
    demo = " ".join(runner.invoke(app, ["demo", "--help"]).output.split())
    for name in ("human", "cv", "idm", "sf-opt", "gnp", "letspi-memory", "letspi-fast"):
        assert name in demo, name


def test_bench_numbers_share_one_format() -> None:
    assert format_number(10.0) == "10" and format_number(10_000.0) == "10,000" and format_number(4103) == "4,103"
    assert format_number(1234.56) == "1,234.6" and format_number(3.14159) == "3.142"
    assert format_number(0.01234) == "0.0123"
    assert "e+" not in format_number(1e4) and "e+" not in format_number(123456789.5)


def test_rationale_is_null_or_text_in_plan_json(tmp_path: Path) -> None:
    path = save_scenarios(straight_road_scenario(neighbours=[VehicleSpec(25.0, 27.0)]), tmp_path / "s.arrow")
    for planner in ("sf", "letspi-memory"):
        result = runner.invoke(app, ["plan", "--scenarios", str(path), "--index", "0", "--planner", planner,
                                     "--llm", "scripted:default", "--no-cache", "--json"])
        assert result.exit_code == 0, result.output
        out = json.loads(result.stdout)
        assert out["rationale"] is None or (isinstance(out["rationale"], str) and out["rationale"].strip())
        for it in out.get("iterations", []):
            assert it["rationale"] is None or it["rationale"].strip()
