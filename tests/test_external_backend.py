"""LLM backends from outside letspi: the ``letspi.llm_backends`` entry-point group, checked when read, read
only for an unknown prefix or a listing, keyed by package and version; the example package installed and
run through ``letspi llm check`` and a ``letspi-fast`` evaluation."""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_evaluation_statistics import _batch
from typer.testing import CliRunner

from letspi.assembly.resolve import Resolver
from letspi.cli.llm import app
from letspi.llm.cache import ResponseCache
from letspi.llm.client import ParamAdvisor
from letspi.llm.schema import FIELD_RANGES
from letspi.llm.spec import (
    BackendKind,
    BackendKindError,
    default_concurrency,
    installed_backends,
    make_backend,
    parse_spec,
)
from letspi.llm.types import UnknownBackendError, message
from letspi.planners.options import PlannerOptions
from letspi.scenario.store import save_scenarios

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "letspi-echo-backend"
OPTS = PlannerOptions(llm="scripted:default", fast_llm="scripted:default", llm_cache=False)

PLUGIN = '''
from pathlib import Path
from letspi.plugin import BackendKind
from letspi.llm.backends.scripted import ScriptedBackend

class Local(ScriptedBackend):
    @property
    def spec(self):
        return f"local:{self.name}"

def build(spec, options):
    return Local(default='{}', name=spec.model)

def bare(spec, options):
    return ScriptedBackend(default='{}', name=spec.model)

def explode(spec, options):
    raise RuntimeError("no GPU here")

def not_a_backend(spec, options):
    return 42

LOCAL = BackendKind("local", build, ("local:/path/to/weights",), "runs local weights", default_concurrency=3,
                    local_weights=lambda s: Path(s.model))
BOOM = BackendKind("boom", explode, ("boom:MODEL",), "a factory that raises")
ODD = BackendKind("odd", not_a_backend, ("odd:MODEL",), "a factory that returns no backend")
BARE = BackendKind("bare", bare, ("bare:MODEL",), "a backend whose spec names another kind")
TAKEN = BackendKind("ollama", build, ("ollama:MODEL",), "takes a built-in prefix")
NOT_A_KIND = ScriptedBackend
'''

ENTRY_POINTS = {"local": "LOCAL", "boom": "BOOM", "odd": "ODD", "bare": "BARE", "ollama": "TAKEN", "cls": "NOT_A_KIND",
                "renamed": "LOCAL", "gone": "NO_SUCH"}


@pytest.fixture(autouse=True)
def _fresh_backends() -> Iterator[None]:
    """Installed kinds are read once per process: each test reads them afresh, and leaves none behind."""
    installed_backends.cache_clear()
    yield
    installed_backends.cache_clear()


@pytest.fixture
def plugins(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An installed distribution (``letspi-test-backends 0.3``: a dist-info on the path) naming the kinds
    of ``PLUGIN`` and a missing attribute in the entry-point group."""
    site = tmp_path / "site"
    (site / "letspi_test_backends-0.3.dist-info").mkdir(parents=True)
    (site / "letspi_test_backends.py").write_text(PLUGIN)
    (site / "letspi_test_backends-0.3.dist-info" / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: letspi-test-backends\nVersion: 0.3\n")
    (site / "letspi_test_backends-0.3.dist-info" / "entry_points.txt").write_text(
        "[letspi.llm_backends]\n" + "".join(f"{n} = letspi_test_backends:{v}\n" for n, v in ENTRY_POINTS.items()))
    monkeypatch.syspath_prepend(str(site))
    return site


def test_built_in_specs_never_read_the_entry_points(plugins: Path) -> None:
    assert parse_spec("openai:m@http://h:1/v1").base_url == "http://h:1/v1"
    assert default_concurrency("ollama:llama3.1:8b") == 8 and default_concurrency("llamacpp:x") == 1
    assert make_backend("scripted:default").spec == "scripted:default"
    with pytest.raises(UnknownBackendError, match="missing model name"):
        parse_spec("ollama:")
    assert Resolver(OPTS).llm("scripted:default").backend is None
    assert installed_backends.cache_info().currsize == 0
    code = ("from typer.testing import CliRunner; from letspi.cli.app import app; "
            "from letspi.llm.spec import installed_backends; CliRunner().invoke(app, ['llm', '--help']); "
            "print(installed_backends.cache_info().currsize)")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(plugins), str(ROOT / "src")])}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "0", out.stderr  # the CLI starts without reading them


def test_an_installed_kind_is_parsed_built_scheduled_and_keyed_by_package_and_weights(
        plugins: Path, tmp_path: Path) -> None:
    weights = tmp_path / "w.bin"
    weights.write_bytes(b"first")
    builtin_key = Resolver(OPTS).llm("scripted:default").key()
    config = Resolver(OPTS).llm(f"LOCAL:{weights}")
    assert config.spec == f"local:{weights}" and config.backend == "letspi-test-backends 0.3"
    assert config.model_sha256 == hashlib.sha256(b"w.bin" + b"first").hexdigest()  # name and bytes
    assert config.model_path == str(weights)
    assert config.identity()["backend"] == "letspi-test-backends 0.3"
    assert "backend" not in Resolver(OPTS).llm("scripted:default").identity()
    assert Resolver(OPTS).llm("scripted:default").key() == builtin_key  # built-in keys do not move
    weights.write_bytes(b"second")
    assert Resolver(OPTS).llm(f"local:{weights}").key() != config.key()  # the weights enter the key
    assert default_concurrency(f"local:{weights}") == 3
    assert make_backend(f"local:{weights}").spec == f"local:{weights}"


def test_the_response_cache_tells_package_versions_apart(plugins: Path, tmp_path: Path) -> None:
    cache, messages = ResponseCache(tmp_path / "cache.sqlite"), [message("user", "hi")]
    assert not ParamAdvisor("local:m", cache=cache).complete(messages, schema=None).cached
    assert ParamAdvisor("local:m", cache=cache).complete(messages, schema=None).cached
    (plugins / "letspi_test_backends-0.3.dist-info" / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: letspi-test-backends\nVersion: 0.4\n")  # an upgrade
    installed_backends.cache_clear()
    assert not ParamAdvisor("local:m", cache=cache).complete(messages, schema=None).cached


@pytest.mark.parametrize(("spec", "message"), [
    ("boom:m", "boom:m: the backend of letspi-test-backends 0.3 failed to start: RuntimeError: no GPU here"),
    ("odd:m", "odd:m: the backend of letspi-test-backends 0.3 returned a int, not an LLMBackend"),
    ("bare:m", "bare:m: the backend of letspi-test-backends 0.3 has spec 'scripted:m', which does not start with "
               "'bare:'"),
    ("cls:m", "letspi_test_backends:NOT_A_KIND (entry point 'cls' of letspi-test-backends 0.3) is a class, "
              "not a letspi BackendKind"),
    ("renamed:m", "entry point 'renamed' of letspi-test-backends 0.3): the entry-point name must be the kind's "
                  "prefix 'local'"),
    ("gone:m", "(entry point 'gone' of letspi-test-backends 0.3): AttributeError"),
])
def test_a_broken_installed_kind_is_one_clear_line_naming_its_package(plugins: Path, spec: str,
                                                                      message: str) -> None:
    with pytest.raises(BackendKindError) as err:
        make_backend(spec)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_a_kind_may_not_take_a_built_in_prefix_and_the_built_in_stays(plugins: Path) -> None:
    problems = installed_backends().problems
    assert "backend prefix 'ollama' exists already" in problems["ollama"]
    assert "letspi-test-backends 0.3" in problems["ollama"]
    assert type(make_backend("ollama:m")).__name__ == "OllamaBackend"
    with pytest.raises(UnknownBackendError, match=r"unknown backend 'hf' \(available: llamacpp, ollama, openai, "
                                                  r"scripted, bare, boom, local, odd\)") as err:
        parse_spec("hf:gpt2")
    assert "local:/path/to/weights" in str(err.value)  # the installed forms are listed too


def test_a_kind_declares_valid_data() -> None:
    def build(spec: object, options: object) -> object:
        raise AssertionError

    with pytest.raises(ValueError, match="lowercase letters"):
        BackendKind("My:kind", build, ("My:kind:x",), "d")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="forms must be spec forms starting with 'x:'"):
        BackendKind("x", build, ("y:m",), "d")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="default_concurrency must be an integer >= 1"):
        BackendKind("x", build, ("x:m",), "d", default_concurrency=0)  # type: ignore[arg-type]


def test_llm_backends_lists_built_in_and_installed_kinds_and_what_is_left_out(plugins: Path) -> None:
    res = CliRunner().invoke(app, ["backends", "--json"])
    assert res.exit_code == 0, res.output
    rows = {row["prefix"]: row for row in json.loads(res.stdout)}
    assert list(rows) == ["llamacpp", "ollama", "openai", "scripted", "bare", "boom", "local", "odd"]
    assert rows["local"]["source"] == "letspi-test-backends 0.3" and rows["local"]["local_weights"] is True
    assert rows["ollama"]["source"] == "built in" and rows["ollama"]["default_concurrency"] == 8
    assert sum(line.startswith("left out: ") for line in res.stderr.splitlines()) == 4  # cls, renamed, gone, ollama


def _installed_example(tmp_path: Path) -> dict[str, str]:
    """The environment of a process that has the example package installed: this one's when it is, else a
    pip --target install of examples/letspi-echo-backend on PYTHONPATH."""
    env = {**os.environ, "LETSPI_CACHE_DIR": str(tmp_path / "cache")}
    try:
        importlib.metadata.distribution("letspi-echo-backend")
        return env
    except importlib.metadata.PackageNotFoundError:
        target, source = tmp_path / "site", tmp_path / "letspi-echo-backend"
        shutil.copytree(EXAMPLE, source, ignore=shutil.ignore_patterns("build", "*.egg-info"))  # builds there
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
                        "--target", str(target), str(source)], check=True, timeout=300)
        return {**env, "PYTHONPATH": os.pathsep.join([str(target), os.environ.get("PYTHONPATH", "")])}


def test_the_example_backend_runs_installed_through_llm_check_and_a_fast_evaluation(tmp_path: Path) -> None:
    env = _installed_example(tmp_path)

    def letspi(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "letspi.cli.app", *args], capture_output=True, text=True,
                              env=env, cwd=tmp_path, timeout=300)

    check = letspi("llm", "check", "echo:x", "--no-cache")
    assert check.returncode == 0, check.stderr
    out = json.loads(check.stdout)
    middle = {name: (low + high) / 2 for name, (low, high) in FIELD_RANGES.items()}
    assert out["model_spec"] == "echo:x" and out["fallback"] is False and out["attempts"] == 1
    assert out["reply"]["tau_s"] == pytest.approx(middle["tau_s"]) and out["reply"]["lane_factor"] == 0.0
    scenarios = save_scenarios(_batch(), tmp_path / "s.arrow")
    collect = letspi("collect", "--scenarios", str(scenarios), "--memory", "m.sqlite", "--llm", "echo:x",
                     "--goals", "kinematic", "--no-cache")
    assert collect.returncode == 0, collect.stderr
    result = letspi("evaluate", "--scenarios", str(scenarios), "--planner", "letspi-fast", "--fast-llm", "echo:x",
                    "--memory", "m.sqlite", "--goals", "kinematic", "--no-cache", "--out", "ev")
    assert result.returncode == 0, result.stderr
    config = json.loads((tmp_path / "ev" / "per_scenario" / "letspi-fast" / "config.json").read_text())
    llm = config["identity"]["llm"]
    assert llm["spec"] == "echo:x" and llm["backend"] == "letspi-echo-backend 0.1.0"  # the package is in the key
    metrics = json.loads((tmp_path / "ev" / "metrics.json").read_text())["planners"]["letspi-fast"]
    assert metrics["fallback_pct"] == 0.0 and metrics["llm_calls_per_scenario"] == 1.0
