"""The prompt fingerprint comes from the prompts as rendered: text changes move it, code edits do not."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import replace
from importlib import resources
from pathlib import Path

import pytest

import letspi
from letspi.assembly import resolve
from letspi.assembly.planners import resolve_planner
from letspi.assembly.resolve import Resolver
from letspi.llm import choice, compact, describe, fingerprint, prompts
from letspi.llm.compact import PROMPT_STYLES
from letspi.llm.schema import VARIANTS
from letspi.method import prompt_samples, reflection
from letspi.method.reflection import METRIC_ORDER
from letspi.planners.options import PlannerOptions

OPTS = PlannerOptions(llm="scripted:default", fast_llm="scripted:default", llm_cache=False)


def _clear_prompt_caches() -> None:
    prompts.prompt_environment.cache_clear()
    prompts.system_prompt.cache_clear()
    compact.compact_system_prompt.cache_clear()
    choice.choice_system_prompt.cache_clear()


@pytest.fixture
def fresh_prompts() -> Iterator[None]:
    """Templates and system prompts rendered anew (they are cached per process) before and after the test."""
    _clear_prompt_caches()
    yield
    _clear_prompt_caches()


def test_the_fingerprint_is_stable_and_is_what_configurations_carry() -> None:
    value = resolve.prompt_sha256()
    assert re.fullmatch(r"[0-9a-f]{64}", value) and value == resolve.prompt_sha256()
    assert Resolver(OPTS).llm("scripted:default").prompt_sha256 == value


def test_comments_and_code_layout_do_not_change_the_fingerprint(tmp_path: Path) -> None:
    """0.x hashed the source of the modules that write prompts: a comment moved every LLM result key."""
    package = tmp_path / "letspi"
    shutil.copytree(Path(letspi.__file__).parent, package, ignore=shutil.ignore_patterns("__pycache__"))
    for module in ("llm/describe.py", "llm/prompts.py", "llm/compact.py", "llm/schema.py", "llm/client.py",
                   "llm/fingerprint.py", "method/reflection.py", "method/phases.py"):
        path = package / module
        source = path.read_text()
        # comments, and a docstring reworded: the code that writes the prompts is edited, not the prompts
        edited = "# edited: a comment only\n" + source.replace('"""', '""" Reworded. ', 1) + "\n# the end\n"
        assert edited != source
        path.write_text(edited)
    code = ("import letspi; from letspi.assembly.resolve import prompt_sha256; "
            "print(letspi.__file__); print(prompt_sha256())")
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    where, value = out.stdout.split()
    assert Path(where).parent == package  # the edited copy was imported
    assert value == resolve.prompt_sha256()


def test_a_number_format_in_the_scene_text_changes_the_fingerprint(monkeypatch: pytest.MonkeyPatch) -> None:
    before = resolve.prompt_sha256()
    monkeypatch.setattr(describe, "_f", lambda v: f"{v:.2f}")
    assert resolve.prompt_sha256() != before


def test_a_template_edit_changes_the_fingerprint_and_the_result_keys(
        monkeypatch: pytest.MonkeyPatch, fresh_prompts: None) -> None:
    before, key = resolve.prompt_sha256(), resolve_planner("letspi-memory", OPTS).key()
    load = prompts._load_template
    monkeypatch.setattr(prompts, "_load_template",
                        lambda name: load(name) + ("\nBe brief." if name == "compact_system.j2" else ""))
    _clear_prompt_caches()
    assert resolve.prompt_sha256() != before
    assert resolve_planner("letspi-memory", OPTS).key() != key


def test_a_template_file_counts_even_where_no_scene_reaches(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    before = resolve.prompt_sha256()
    package = tmp_path / "letspi"
    shutil.copytree(Path(str(resources.files("letspi"))) / "prompts", package / "prompts")
    monkeypatch.setattr(fingerprint.resources, "files", lambda name: package)
    assert resolve.prompt_sha256() == before  # an identical copy: the same fingerprint
    template = package / "prompts" / "physics_user.j2"
    template.write_text(template.read_text() + "\n{# a branch no sample takes #}")
    assert resolve.prompt_sha256() != before


def test_the_compact_reply_format_and_the_safety_report_text_count(monkeypatch: pytest.MonkeyPatch) -> None:
    before = resolve.prompt_sha256()
    with monkeypatch.context() as m:
        m.setitem(compact.REPLY_DECIMALS, "k_np", 2)  # the rejected answer of a refine prompt
        assert resolve.prompt_sha256() != before
    assert resolve.prompt_sha256() == before
    with monkeypatch.context() as m:
        m.setattr(reflection, "_fmt", lambda value, unit: f"{value:.3f} {unit}")  # the safety report (method layer)
        assert resolve.prompt_sha256() != before
    assert resolve.prompt_sha256() == before


def test_every_template_file_is_rendered_by_the_samples(monkeypatch: pytest.MonkeyPatch, fresh_prompts: None) -> None:
    """A new template must get a sample (``letspi.llm.fingerprint``), else its branches go unchecked."""
    loaded: list[str] = []
    load = prompts._load_template
    monkeypatch.setattr(prompts, "_load_template", lambda name: loaded.append(name) or load(name))
    fingerprint.prompt_samples()
    templates = set(fingerprint.template_files())
    assert templates and templates <= set(loaded), sorted(templates - set(loaded))


def test_every_prompt_style_and_variant_has_samples_and_a_new_style_cannot_be_missed(
        monkeypatch: pytest.MonkeyPatch) -> None:
    samples = fingerprint.prompt_samples()
    for scene in fingerprint.FINGERPRINT_SCENES:
        for style in PROMPT_STYLES:
            assert any(name.startswith(f"{scene}/{style}/") for name in samples), (scene, style)
    assert {f"corrective/{v}" for v in VARIANTS} <= set(samples)
    # both forms of every optional part of the paper prompts
    texts = {name: "\n".join(m["content"] for m in msgs) if isinstance(msgs, list) else msgs
             for name, msgs in samples.items()}
    assert any(len(msgs) == 4 for msgs in samples.values())  # the reflection round as a follow-up turn
    for marker in ("## Memory", "## Safety analysis report", "## Guidance", "## Validated examples", "Rejected:",
                   "None within range.", "speed limit none", "TTC 0.0 s", "not closing", "do not go left",
                   "do not go right", "truck"):
        assert any(marker in t for t in texts.values()), marker
    for marker in ("## Memory", "## Guidance", "Rejected:"):
        assert any(marker not in t for name, t in texts.items() if "/" in name), marker
    monkeypatch.setattr(fingerprint, "PROMPT_STYLES", (*PROMPT_STYLES, "chatty"))
    with pytest.raises(RuntimeError, match="chatty.*STYLE_SAMPLES"):
        resolve.prompt_sha256()


def test_every_violation_kind_is_in_the_safety_report_samples(monkeypatch: pytest.MonkeyPatch) -> None:
    texts = prompt_samples.prompt_text_samples()
    report = texts["report/unsafe+proposal"]
    assert report.count("\n- At t=") == len(METRIC_ORDER) and report.startswith("Safety analysis")
    monkeypatch.setattr(prompt_samples, "METRIC_ORDER", (*METRIC_ORDER, "jerk"))
    with pytest.raises(RuntimeError, match="jerk.*_VIOLATIONS"):
        resolve.prompt_sha256()


def test_a_change_in_the_scene_set_changes_the_fingerprint(monkeypatch: pytest.MonkeyPatch) -> None:
    before = resolve.prompt_sha256()
    scenes = dict(fingerprint.FINGERPRINT_SCENES)
    build = scenes["busy"]
    scenes["busy"] = lambda: (replace(build()[0], location_id=build()[0].location_id + 1), build()[1])
    monkeypatch.setattr(fingerprint, "FINGERPRINT_SCENES", scenes)
    assert resolve.prompt_sha256() != before


def test_the_cli_prints_the_fingerprint_and_writes_every_sample(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from letspi.cli.app import app

    result = CliRunner().invoke(app, ["llm", "fingerprint", "--out", str(tmp_path / "samples")])
    assert result.exit_code == 0, result.output
    assert result.stdout.strip().splitlines()[-1] == resolve.prompt_sha256()
    written = {str(p.relative_to(tmp_path / "samples")) for p in (tmp_path / "samples").rglob("*.txt")}
    expected = {f"{name}.txt" for name in [*fingerprint.prompt_samples(), *prompt_samples.prompt_text_samples()]}
    assert written == expected
    turn = (tmp_path / "samples" / "busy" / "paper" / "physics+memories+turn.txt").read_text()
    assert turn.startswith("[system]\n") and "[assistant]\n" in turn and "## Refinement" in turn
