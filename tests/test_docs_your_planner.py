"""docs/your-planner.md runs as written: its code blocks, in order, in a directory laid out as a clone after the
README's set-up (``letspi-demo/scenarios.arrow`` and ``letspi-demo/evaluation/``, here of 16 synthetic windows).

A ``python`` block whose first line is ``# PATH`` is a file the reader saves; any other ``python`` block runs
as a script; every command of a ``bash`` block runs and must succeed. A block after ``<!-- slow ...`` runs
only in the slow test (it simulates traffic with SUMO); one after ``<!-- not run ...`` never does (it
installs a package: ``tests/test_external_planner.py`` covers that).
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
from test_evaluation_statistics import _batch

import letspi.api as lp
from letspi.assembly.planner_table import BUILT_IN
from letspi.scenario.store import save_scenarios

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "your-planner.md"
FENCE = re.compile(r"^```(\w*)\s*$")


@dataclass(frozen=True)
class Block:
    lang: str
    text: str
    line: int
    marker: str  # "", "slow" or "not run": the HTML comment on the line before the fence


def blocks(text: str) -> list[Block]:
    out, lines, i = [], text.splitlines(), 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if m is None:
            i += 1
            continue
        before = lines[i - 1].strip() if i else ""
        marker = re.match(r"<!-- (slow|not run)", before)
        end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith("```"))
        out.append(Block(m.group(1), "\n".join(lines[i + 1:end]), i + 1, marker.group(1) if marker else ""))
        i = end + 1
    return out


def commands(block: Block) -> list[list[str]]:
    """The shell commands of a bash block (continuations joined, comments dropped)."""
    joined = block.text.replace("\\\n", " ")
    return [words for line in joined.splitlines() if (words := shlex.split(line, comments=True))]


def _clone(tmp: Path) -> Path:
    """A directory as the README's set-up leaves it, with the repository's examples/."""
    demo = tmp / "letspi-demo"
    demo.mkdir()
    save_scenarios(_batch(), demo / "scenarios.arrow")
    lp.evaluate(["sf", "cv"], demo / "scenarios.arrow", demo / "evaluation")  # the demo's baselines, default options
    (tmp / "examples").symlink_to(ROOT / "examples")
    return tmp


def _run(cwd: Path, args: list[str], what: str) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "COLUMNS": "200"}  # letspi only, never the reader's folder
    if args[0] == "letspi":  # as the installed command runs: the working directory is not on the path (-P)
        args = [sys.executable, "-P", "-c", "from letspi.cli.app import main; main()", *args[1:]]
    elif args[0] == "python":
        args = [sys.executable, *args[1:]]
    out = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, f"{what}: {' '.join(args)}\n{out.stdout[-3000:]}\n{out.stderr[-3000:]}"


def _run_page(cwd: Path, *, slow: bool) -> int:
    ran = 0
    for block in blocks(PAGE.read_text(encoding="utf-8")):
        where = f"{PAGE.name}:{block.line}"
        if block.marker == "not run" or (block.marker == "slow" and not slow):
            continue
        if block.lang == "python" and (first := block.text.splitlines()[0]).startswith("# ") and "/" in first:
            target = cwd / first[2:].strip()
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(block.text + "\n")
        elif block.lang == "python":
            script = cwd / f"block_{block.line}.py"
            script.write_text(block.text + "\n")
            _run(cwd, ["python", script.name], where)
            ran += 1
        elif block.lang == "bash":
            for args in commands(block):
                assert args[0] == "letspi", f"{where}: only letspi commands run here: {args}"
                _run(cwd, args, where)
                ran += 1
    return ran


def test_the_page_runs_as_written(tmp_path: Path) -> None:
    cwd = _clone(tmp_path)
    assert _run_page(cwd, slow=False) == 9  # 8 commands and the Python script
    assert (cwd / "runs/mine/report.html").is_file() and (cwd / "runs/mine/compare/compare.html").is_file()
    assert {p.name for p in (cwd / "runs/mine/per_scenario").iterdir()} == {"sf", "cv-gap", "cv-gap-v2"}
    assert (cwd / "runs/mine-api/per_scenario/cv-gap-2s/config.json").is_file()


@pytest.mark.slow
@pytest.mark.sumo
def test_the_page_runs_as_written_with_its_benchmark_suite(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("LETSPI_BENCHMARK_CACHE", str(tmp_path / "cache"))
    assert _run_page(_clone(tmp_path), slow=True) == 10


def test_the_keyword_table_is_every_option_whose_name_is_not_its_flag() -> None:
    text = PAGE.read_text(encoding="utf-8")
    rows = re.findall(r"^\| `(--[\w-]+)` \| `(\w+)=` \| `(\w+)=` \|$", text, re.M)
    expected = [(o.cli_flag, o.keyword, o.name) for o in BUILT_IN.options() if o.keyword != o.name]
    assert sorted(rows) == sorted(expected)
