"""README.md, docs/ and notes/ name only code that exists, and nothing outside the repository.

* A file path ending in ``.py`` names a file of the repository, matched by its tail: ``describe.py``,
  ``llm/describe.py`` and ``src/letspi/llm/describe.py`` all name ``src/letspi/llm/describe.py``.
* A dotted ``letspi.x.y`` names a module, and a name after the module an attribute of it.
* No path outside the repository (``/work/``, ``/tmp/``, ``/root/``, ``/home/``) in those files, in the
  package's Python source or in the JSON files it ships (``letspi/data``: provenance names files, not the
  directories of the machine that wrote them): a note that cites an input or a script the reader cannot
  have is not one that can be rerun. Nor does the source cite sections of a reference file outside it.
* Every ``letspi`` command line in notes/ exists with its options (the checker of ``test_docs``).
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path
from typing import Any

import pytest
import typer
from test_docs import check_command, extract_commands

from letspi.benchmark.suites import SUITES_GROUP
from letspi.cli.app import COMMANDS_GROUP, app
from letspi.cli.viz import REPORTS_GROUP
from letspi.llm.spec import ENTRY_POINT_GROUP as LLM_BACKENDS_GROUP

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "letspi"
#: the package root of each top-level name a text may cite (letspi and its companion distributions)
PACKAGES = {"letspi": PACKAGE, "letspi_train": ROOT / "packages" / "letspi-train" / "src" / "letspi_train",
            "letspi_interop": ROOT / "packages" / "letspi-interop" / "src" / "letspi_interop"}
TEXT_FILES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "notes").glob("*.md"))]
#: Files the docs name as examples of what a reader would add (recipes), not as existing code.
EXAMPLE_FILES = frozenset({"src/letspi/planners/brake.py", "src/letspi/llm/backends/mybackend.py",
                           "my_planners/cv_gap.py"})  # the reader's own planner (docs/your-planner.md)
PY_PATH = re.compile(r"(?<![\w/.-])((?:[\w.*-]+/)*[\w-]+\.py)\b")
DOTTED = re.compile(r"(?<![\w.])letspi(?:_train|_interop)?(?:\.[A-Za-z_]\w*)+")
OUTSIDE = re.compile(r"(?<![\w.~-])/(?:work|tmp|root|home)/[\w.-]*")


def _repository_files() -> list[str]:
    out = [p.name for p in ROOT.glob("*.py")]
    for folder in ("src", "packages", "tests", "scripts", "benchmarks", "notes", "docs", ".ci", "examples"):
        out += [str(p.relative_to(ROOT)) for p in (ROOT / folder).rglob("*.py") if "__pycache__" not in p.parts]
    return out


def missing_py_paths(text: str, files: list[str]) -> list[str]:
    """The ``.py`` paths of ``text`` that name no file of ``files`` (repository-relative paths)."""
    found = [(p, p.replace("../", "")) for p in PY_PATH.findall(text)]  # a docs/ link: ../examples/x.py
    return [p for p, q in found
            if p not in EXAMPLE_FILES and not any(f == q or f.endswith("/" + q) for f in files)]


def missing_dotted(text: str) -> list[str]:
    """The ``letspi.x.y`` names of ``text`` that name no module (nor an attribute right after one)."""
    bad = []
    for name in DOTTED.findall(text):
        if name in (LLM_BACKENDS_GROUP, COMMANDS_GROUP, SUITES_GROUP, REPORTS_GROUP):  # entry-point groups
            continue
        parts = name.split(".")
        root = PACKAGES[parts[0]]
        k = len(parts)
        while k > 1 and not ((root.joinpath(*parts[1:k]).with_suffix(".py")).is_file()
                             or (root.joinpath(*parts[1:k]) / "__init__.py").is_file()):
            k -= 1
        if k == len(parts):
            continue
        if k == 1:
            bad.append(name)
            continue
        try:
            module = importlib.import_module(".".join(parts[:k]))
        except ModuleNotFoundError:  # a companion (or its torch) not installed here: its file exists
            if parts[0] == "letspi":
                raise
            continue
        if not hasattr(module, parts[k]):
            bad.append(name)
    return bad


def test_the_checkers_find_what_is_missing() -> None:
    files = ["src/letspi/llm/describe.py", "tests/test_docs.py"]
    text = "`describe.py`, `llm/describe.py`, `src/letspi/llm/describe.py`, `assembly/configs.py`, `xdescribe.py`"
    assert missing_py_paths(text, files) == ["assembly/configs.py", "xdescribe.py"]
    text = "letspi.llm.describe.describe_scenario, letspi.llm, letspi.assembly.configs, letspi.llm.describe.nothing."
    assert missing_dotted(text) == ["letspi.assembly.configs", "letspi.llm.describe.nothing"]
    assert OUTSIDE.findall("see /work/runs/x.py and /tmp/y, not ~/.cache/letspi or src/letspi/tmp/") == [
        "/work/runs", "/tmp/y"]


@pytest.mark.parametrize("doc", TEXT_FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_docs_and_notes_name_existing_modules_only(doc: Path) -> None:
    text = doc.read_text(encoding="utf-8")
    files = _repository_files()
    bad = [f"{doc.relative_to(ROOT)}:{i}: {p}" for i, line in enumerate(text.splitlines(), start=1)
           for p in [*missing_py_paths(line, files), *missing_dotted(line)]]
    assert not bad, "\n".join(bad)


def test_no_path_outside_the_repository() -> None:
    shipped = sorted((PACKAGE / "data").rglob("*.json"))  # fitted files, adapter and model manifests
    assert len(shipped) >= 4
    sources = [*TEXT_FILES, *sorted(PACKAGE.rglob("*.py")), *shipped]
    bad = [f"{p.relative_to(ROOT)}:{i}: {m}" for p in sources
           for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), start=1) for m in OUTSIDE.findall(line)]
    assert not bad, "\n".join(bad)


def test_the_source_cites_nothing_outside_the_repository() -> None:
    """Docstrings state a fact or link docs/; a numbered section of a file the reader lacks is neither."""
    cite = re.compile(r"REFERENCE(?: §|'s)")
    files = [*sorted(PACKAGE.rglob("*.py")), *sorted((ROOT / "tests").glob("*.py"))]
    bad = [f"{p.relative_to(ROOT)}:{i}" for p in files
           for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), start=1)
           if cite.search(line) and p.name != "test_notes.py"]
    assert not bad, "\n".join(bad)


@pytest.fixture(scope="module")
def root() -> Any:
    return typer.main.get_command(app)


def test_every_command_in_the_notes_exists(root: Any) -> None:
    commands = [c for note in sorted((ROOT / "notes").glob("*.md"))
                for c in extract_commands(note.read_text(encoding="utf-8"), str(note.relative_to(ROOT)))]
    assert len(commands) >= 50  # the check would pass vacuously on a parser that finds nothing
    bad = [e for c in commands for e in check_command(root, c).errors]
    assert not bad, "\n".join(bad)
