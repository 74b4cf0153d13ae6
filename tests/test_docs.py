"""The docs show only commands and options that exist.

Every ``letspi ...`` command line in the README and ``docs/*.md`` is parsed from the fenced
``bash``/``sh``/``shell`` blocks (every line), ``console`` blocks (lines starting with ``$ ``) and
inline code spans that start with ``letspi ``. Each must name an existing command path, and every
``--option`` it uses must be a parameter of that command (or of a group on its path), read from
the click command behind ``letspi.cli.app.app``. ``...`` stands for elided arguments.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path
from typing import Any

import pytest
import typer
from typer.testing import CliRunner

from benchmarks.speed import app as speed_app
from letspi.assembly.planner_table import BUILT_IN
from letspi.cli.app import COMMANDS, COMPANIONS, app
from letspi.evaluation.summary import outputs_reference_markdown
from letspi.metrics import reference_markdown

ROOT = Path(__file__).resolve().parents[1]
DOC_FILES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
SHELL_LANGS = {"bash", "sh", "shell"}
OPERATORS = {"&&", "||", "|", ";", "&", "(", ")"}
REDIRECTS = {">", ">>", "<", "2>", "2>&1", ">&"}
ENV_ASSIGNMENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*=")
FENCE = re.compile(r"^(\s*)(`{3,}|~{3,})\s*([\w+-]*)")
METRICS_REFERENCE = ROOT / "docs" / "metrics-reference.md"
GENERATED_MARK = "<!-- generated below: letspi.metrics.reference_markdown() -->"


@dataclass(frozen=True)
class DocCommand:
    """One ``letspi`` invocation found in a document: where it is and its argument tokens."""

    source: str  # "FILE:LINE"
    args: tuple[str, ...]  # the tokens after ``letspi``


def _join_continuations(lines: list[tuple[int, str]]) -> list[tuple[int, str]]:
    """Join lines ending in a backslash with the next one (keeping the first line's number)."""
    joined: list[tuple[int, str]] = []
    start, buf = None, ""
    for lineno, line in lines:
        if start is None:
            start = lineno
        stripped = line.rstrip()
        if stripped.endswith("\\"):
            buf += stripped[:-1] + " "
            continue
        joined.append((start, buf + line))
        start, buf = None, ""
    if start is not None:
        joined.append((start, buf))
    return joined


def _tokens(line: str) -> list[str]:
    """Shell words of one logical line; comments dropped, operators (``&&``, ``|``, ``;``) as tokens."""
    lexer = shlex.shlex(line, posix=True, punctuation_chars=";&|()<>")
    lexer.whitespace_split = True
    lexer.commenters = "#"
    return list(lexer)


LETSPI: tuple[str, ...] = ("letspi",)
SPEED: tuple[str, ...] = ("python", "-m", "benchmarks.speed")


def letspi_invocations(line: str, program: tuple[str, ...] = LETSPI) -> list[list[str]]:
    """The argument lists of every ``program`` command (``letspi``, or ``SPEED``) in one shell line (after
    ``VAR=x`` prefixes, ``&&``, ``||``, ``|`` or ``;``); redirections and their targets are dropped."""
    found: list[list[str]] = []
    segment: list[str] = []
    for tok in [*_tokens(line), ";"]:
        if tok in OPERATORS:
            while segment and ENV_ASSIGNMENT.match(segment[0]):
                segment.pop(0)
            if tuple(segment[:len(program)]) == program:
                args, skip = [], False
                for arg in segment[len(program):]:
                    if skip:
                        skip = False
                    elif arg in REDIRECTS:
                        skip = True
                    else:
                        args.append(arg)
                found.append(args)
            segment = []
        else:
            segment.append(tok)
    return found


def extract_commands(text: str, source: str, program: tuple[str, ...] = LETSPI) -> list[DocCommand]:
    """Every ``program`` invocation of a Markdown text (see the module docstring for where)."""
    inline = re.compile(rf"(?<!`)`({re.escape(' '.join(program))} [^`]+)`(?!`)")
    commands: list[DocCommand] = []
    lang, fence, block = None, "", []  # inside a fence: its language and the fence string
    for lineno, line in enumerate(text.splitlines(), start=1):
        m = FENCE.match(line)
        if lang is None and m:
            lang, fence, block = m.group(3).lower(), m.group(2), []
            continue
        if lang is not None and line.strip().startswith(fence[0] * len(fence)) and not line.strip().strip(fence[0]):
            if lang in SHELL_LANGS:
                logical = _join_continuations(block)
            elif lang == "console":
                logical = [(n, ln.strip()[2:]) for n, ln in block if ln.strip().startswith("$ ")]
            else:
                logical = []
            for n, ln in logical:
                commands += [DocCommand(f"{source}:{n}", tuple(a)) for a in letspi_invocations(ln, program)]
            lang = None
            continue
        if lang is not None:
            block.append((lineno, line))
        else:
            for span in inline.findall(line):
                commands += [DocCommand(f"{source}:{lineno}", tuple(a)) for a in letspi_invocations(span, program)]
    return commands


def _option_names(command: Any) -> dict[str, bool]:
    """Option name -> whether it takes a value, for the click ``command`` (``--help`` included)."""
    names = {"--help": False}
    for param in command.params:
        if param.param_type_name == "option":
            takes_value = not (param.is_flag or param.count)
            for name in [*param.opts, *param.secondary_opts]:
                names[name] = takes_value
    return names


@dataclass(frozen=True)
class Checked:
    """What checking one documented invocation found: errors, the command path, and each option
    with the command path it was given at (``()`` for ``letspi`` itself)."""

    errors: list[str]
    path: tuple[str, ...]
    options: list[tuple[tuple[str, ...], str]]


def _names_a_kind_from_outside(args: tuple[str, ...]) -> bool:
    """Whether a command names a planner kind letspi does not ship (``--planner pkg.mod:NAME`` or an installed
    kind): its options are that kind's flags, which the command gains when it runs; the pages that use them
    run their commands (tests/test_docs_your_planner.py) or install the kind (tests/test_external_planner.py)."""
    kinds = [b.partition("=")[2] or b for a, b in pairwise(args) if a == "--planner"]
    return any(":" in kind or kind not in BUILT_IN.names for kind in kinds)


def check_command(root: Any, cmd: DocCommand) -> Checked:
    """Walk one documented invocation down the click command tree (``root``)."""
    errors: list[str] = []
    path: list[str] = []
    used: list[tuple[tuple[str, ...], str]] = []
    if cmd.args and cmd.args[0] in COMPANIONS and cmd.args[0] not in COMMANDS:
        return Checked(errors, (), used)  # its companion distribution is not installed here: CI checks it
    current = root
    options = _option_names(current)
    expect_value = False
    own_kind = _names_a_kind_from_outside(cmd.args)
    for arg in cmd.args:
        if expect_value:
            expect_value = False
            continue
        if arg in ("...", "…"):
            continue
        if arg.startswith("-") and arg != "-":
            name = arg.split("=", 1)[0]
            if name not in options and own_kind:  # the kind's own flag: checked where the command runs
                continue
            if name not in options:
                errors.append(f"{cmd.source}: `{' '.join(['letspi', *path])}` has no option {name}")
            else:
                used.append((tuple(path), name))
                expect_value = options[name] and "=" not in arg
            continue
        if hasattr(current, "commands"):  # a group: the word names a sub-command
            sub = current.commands.get(arg)
            if sub is None:
                errors.append(f"{cmd.source}: `{' '.join(['letspi', *path])}` has no command {arg!r} "
                              f"(commands: {', '.join(sorted(current.commands))})")
                break
            path.append(arg)
            current = sub
            options = _option_names(current)
        # else: a positional argument of a leaf command, nothing to check
    return Checked(errors, tuple(path), used)


@pytest.fixture(scope="module")
def root() -> Any:
    """The click command tree of the app (typer may vendor click, so it is read by duck typing)."""
    return typer.main.get_command(app)


@pytest.fixture(scope="module")
def documented() -> list[DocCommand]:
    commands: list[DocCommand] = []
    for doc in DOC_FILES:
        commands += extract_commands(doc.read_text(encoding="utf-8"), str(doc.relative_to(ROOT)))
    return commands


def test_the_docs_exist_and_show_commands(documented):
    assert (ROOT / "docs").is_dir()
    assert len(DOC_FILES) >= 10
    assert len(documented) >= 50  # the check would pass vacuously on a parser that finds nothing


def test_every_documented_command_and_option_exists(root, documented):
    errors = [e for cmd in documented for e in check_command(root, cmd).errors]
    assert not errors, "\n".join(errors)


def test_every_self_benchmark_command_in_the_docs_and_notes_exists() -> None:
    """``python -m benchmarks.speed ...`` lines (repository only) name its commands and options."""
    speed = typer.main.get_command(speed_app)
    commands = []
    for doc in [*DOC_FILES, *sorted((ROOT / "notes").glob("*.md"))]:
        commands += extract_commands(doc.read_text(encoding="utf-8"), str(doc.relative_to(ROOT)), SPEED)
    assert len(commands) >= 10
    errors = [e for cmd in commands for e in check_command(speed, cmd).errors]
    assert not errors, "\n".join(errors)


def test_every_documented_command_path_answers_help_with_its_options(root, documented):
    """``letspi PATH --help`` of each documented command path renders (in-process) and shows every
    option the docs use there."""
    wanted: dict[tuple[str, ...], set[str]] = {}
    for cmd in documented:
        checked = check_command(root, cmd)
        wanted.setdefault(checked.path, set())
        for path, option in checked.options:
            wanted.setdefault(path, set()).add(option)
    runner = CliRunner()
    for path, options in sorted(wanted.items()):
        result = runner.invoke(app, [*path, "--help"], terminal_width=200)
        assert result.exit_code == 0, f"letspi {' '.join(path)} --help: {result.output}"
        missing = [o for o in sorted(options) if not re.search(rf"(?<![\w-]){re.escape(o)}(?![\w-])", result.output)]
        assert not missing, f"letspi {' '.join(path)} --help does not show {missing}"


def metrics_reference_text() -> str:
    """docs/metrics-reference.md as it should be: its hand-written head, then the generated reference."""
    head = METRICS_REFERENCE.read_text(encoding="utf-8").split(GENERATED_MARK)[0]
    return f"{head}{GENERATED_MARK}\n\n{reference_markdown().rstrip()}\n\n{outputs_reference_markdown().rstrip()}\n"


def test_metrics_reference_page_is_generated_from_the_registry():
    assert METRICS_REFERENCE.read_text(encoding="utf-8") == metrics_reference_text(), (
        "docs/metrics-reference.md is stale: regenerate it with `python tests/test_docs.py`")


LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def heading_anchors(text: str) -> set[str]:
    """GitHub-style anchors of a Markdown text's headings (lower case, punctuation dropped, spaces -> '-')."""
    anchors: set[str] = set()
    in_fence = False
    for line in text.splitlines():
        if FENCE.match(line):
            in_fence = not in_fence
        elif not in_fence and line.startswith("#"):
            title = line.lstrip("#").strip().lower()
            anchors.add(re.sub(r"[^\w\- ]", "", title).replace(" ", "-"))
    return anchors


def test_relative_links_point_at_files_and_headings_that_exist():
    errors = []
    for doc in DOC_FILES:
        for target in LINK.findall(doc.read_text(encoding="utf-8")):
            if "://" in target or target.startswith("mailto:"):
                continue
            path, _, anchor = target.partition("#")
            dest = (doc.parent / path).resolve() if path else doc
            if not dest.exists():
                errors.append(f"{doc.relative_to(ROOT)}: {target}: no such file")
            elif anchor and dest.suffix == ".md" and anchor not in heading_anchors(dest.read_text(encoding="utf-8")):
                errors.append(f"{doc.relative_to(ROOT)}: {target}: no such heading")
    assert not errors, "\n".join(errors)


# the checker itself ------------------------------------------------------------------------------

FAKE_DOC = """\
Intro with `letspi evaluate --no-such-inline x` inline and `letspi-fast` (not a command).

```bash
# a comment: letspi evaluate --in-a-comment
letspi data generate --out d --minutes 3 --seed 0   # trailing comment --also-ignored
letspi evaluate --scenarios s.arrow --planner sf \\
    --frobnicate 3 --out ev
LETSPI_GOAL_WEIGHTS=w letspi evaluate ... --mode closed-loop-log && letspi data nosuch --x 1
pip install -e . && letspi demo --no-shield | tee log.txt
letspi --debug planners --json > out.json
```

```
letspi evaluate --not-checked-outside-shell-blocks
```

```console
$ letspi report ev --bogus
output line letspi compare --also-not-a-command
```
"""


def test_checker_finds_commands_in_every_form():
    found = [(c.source, c.args) for c in extract_commands(FAKE_DOC, "fake.md")]
    assert found == [
        ("fake.md:1", ("evaluate", "--no-such-inline", "x")),
        ("fake.md:5", ("data", "generate", "--out", "d", "--minutes", "3", "--seed", "0")),
        ("fake.md:6", ("evaluate", "--scenarios", "s.arrow", "--planner", "sf", "--frobnicate", "3", "--out", "ev")),
        ("fake.md:8", ("evaluate", "...", "--mode", "closed-loop-log")),
        ("fake.md:8", ("data", "nosuch", "--x", "1")),
        ("fake.md:9", ("demo", "--no-shield")),
        ("fake.md:10", ("--debug", "planners", "--json")),
        ("fake.md:18", ("report", "ev", "--bogus")),
    ]


def test_checker_reports_unknown_options_and_commands(root):
    errors = [e for c in extract_commands(FAKE_DOC, "fake.md") for e in check_command(root, c).errors]
    assert errors == [
        "fake.md:1: `letspi evaluate` has no option --no-such-inline",
        "fake.md:6: `letspi evaluate` has no option --frobnicate",
        errors[2],
        "fake.md:18: `letspi report` has no option --bogus",
    ]
    assert errors[2].startswith("fake.md:8: `letspi data` has no command 'nosuch' (commands: ")


def test_heading_anchors_follow_the_forge_rule():
    text = "## Results you can trust: keys, timing\n```\n# a shell comment\n```\n### One run: `letspi demo`\n"
    assert heading_anchors(text) == {"results-you-can-trust-keys-timing", "one-run-letspi-demo"}


def test_checker_accepts_negated_flags_and_option_values_that_look_like_commands(root):
    cmd = DocCommand("x:1", ("--debug", "evaluate", "--planner", "data", "--no-cache", "--replan-s=fast=2.5",
                             "--out", "ev"))
    assert check_command(root, cmd) == Checked([], ("evaluate",), [
        ((), "--debug"), (("evaluate",), "--planner"), (("evaluate",), "--no-cache"), (("evaluate",), "--replan-s"),
        (("evaluate",), "--out")])


if __name__ == "__main__":  # regenerate docs/metrics-reference.md
    METRICS_REFERENCE.write_text(metrics_reference_text(), encoding="utf-8")
    print(f"wrote {METRICS_REFERENCE}")


def test_no_unfilled_placeholder_is_left_in_a_table_or_a_figure() -> None:
    """A draft's stand-in for a number yet to be measured (a cell ``| DENSE3_FAST |``, a line ending ``: SPEEDUP``)
    must not ship: every cell is a measured figure or says it was not measured."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "notes").glob("*.md"))]
    cell = re.compile(r"\|\s*[A-Z][A-Z0-9]{2,}(?:_[A-Z0-9]{3,})+\s*(?=\|)")
    line_end = re.compile(r": (?:SPEEDUP|DENSE|TODO|TBD|XXX|FILL)\w*$")
    found = [f"{p.relative_to(ROOT)}:{n}: {line.strip()[:80]}" for p in pages
             for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
             if cell.search(line) or line_end.search(line.rstrip())]
    assert not found, "\n".join(found)
