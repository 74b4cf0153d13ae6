"""CI does what a newcomer does: the README's two set-up commands, verbatim, before anything else."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def readme_setup_commands() -> list[str]:
    """The README's set-up commands: the first two lines that start with ``pip install``."""
    lines = [line.strip() for line in (REPO / "README.md").read_text(encoding="utf-8").splitlines()]
    return [line for line in lines if line.startswith("pip install ")][:2]


def ci_lines() -> list[str]:
    return [line.strip() for line in (REPO / ".ci" / "run").read_text(encoding="utf-8").splitlines()
            if line.strip() and not line.strip().startswith("#")]


def test_the_readme_has_a_main_job_and_a_test_command() -> None:
    main, tests = readme_setup_commands()
    assert main.startswith("pip install -e .") and "letspi " in main
    assert tests.startswith('pip install -e ".[dev]"') and tests.endswith("pytest")


def test_ci_runs_the_readme_commands_verbatim_before_installing_anything_else() -> None:
    lines = ci_lines()
    commands = readme_setup_commands()
    for command in commands:
        assert command in lines, f".ci/run does not run the README's {command!r} verbatim"
    first_readme = min(lines.index(c) for c in commands)
    installs = [i for i, line in enumerate(lines) if re.search(r"\bpip install\b", line)]
    assert installs and installs[0] == first_readme, "nothing may be installed before the README's commands"
    assert lines.index(commands[0]) < lines.index(commands[1])
    assert lines.index("python3 -m venv \"$VENV\"") < first_readme  # in a fresh venv


def test_ci_builds_llama_cpp_as_the_readme_does() -> None:
    text = (REPO / ".ci" / "run").read_text(encoding="utf-8")
    assert not re.search(r"^\s*(export\s+)?CMAKE_ARGS=", text, re.M), "no build flags the README does not give"
    assert "--no-cache-dir" not in text
