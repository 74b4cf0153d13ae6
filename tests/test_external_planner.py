"""Planners from outside letspi (issue 27 item 4): by import path and through the entry-point group of an
installed package, with the same keyed, resumable, timed harness as a built-in kind, and on a leaderboard."""

from __future__ import annotations

import importlib.metadata
import json
import os
import pickle
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_evaluation_statistics import _batch

import letspi.api as lp
from letspi.assembly import planner_table as table_module
from letspi.assembly.planner_table import PlannerKindError, kind_origin, load_kind, planner_table
from letspi.evaluation.results import EvaluationDirError
from letspi.scenario.store import save_scenarios
from letspi.simulation.spec import PlannerSpec, reads_recorded_future

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "letspi-gap-keeper"

PLUGIN = '''
from typing import Literal
from letspi.plugin import Config, FutureUse, PlannerKind, PlannerOption
from letspi.planners.cv import ConstantVelocityPlanner

SCALE = PlannerOption("{prefix}scale", float, 1.0, "a setting")

class MyConfig(Config):
    kind: Literal["my-cv"] = "my-cv"
    {version}
    scale: float = 1.0

def resolve(r):
    return MyConfig(scale=r.options.get(SCALE))

def build(b, c, label):
    return ConstantVelocityPlanner(name=label), 0.0

KIND = PlannerKind("{name}", "a test plug-in", MyConfig, resolve, build, options=(SCALE,), future=FutureUse.NEVER)
NOT_A_KIND = ConstantVelocityPlanner
'''


def _plugin(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, module: str, *, version: str = 'version: str = "1"',
            prefix: str = "my_cv_", name: str = "my-cv") -> str:
    (tmp_path / f"{module}.py").write_text(PLUGIN.format(version=version, prefix=prefix, name=name))
    monkeypatch.syspath_prepend(str(tmp_path))
    return module


@pytest.fixture(autouse=True)
def _fresh_kinds(monkeypatch: pytest.MonkeyPatch) -> None:
    """Kinds loaded by import path stay for the process: each test starts without any."""
    monkeypatch.setattr(table_module, "_BY_PATH", {})


def test_a_kind_by_import_path_is_evaluated_keyed_and_resumed_like_a_built_in(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    mod = _plugin(tmp_path, monkeypatch, "plugin_ok")
    built = lp.planners("sf", f"{mod}:KIND", f"wide={mod}:KIND", goals="kinematic", my_cv_scale=2.0)
    assert [b.name for b in built] == ["sf", "my-cv", "wide"]  # labelled by the kind's name unless given
    assert "my-cv" in planner_table().names and kind_origin("my-cv") == f"import path {mod}:KIND"
    assert not built[1].reads_future and built[1].config.scale == 2.0  # type: ignore[attr-defined]
    results = lp.evaluate(built[:2], _batch(), tmp_path / "ev")
    record = json.loads((tmp_path / "ev" / "per_scenario" / "my-cv" / "config.json").read_text())
    assert record["kind"] == "my-cv" and record["identity"]["version"] == "1" and record["key"] == built[1].key
    assert results.reference == "sf" and "my-cv" in results.raw["paired"]["planners"]
    assert len(results.per_scenario("my-cv")) == 16
    # a worker process builds it from its description: the import path travels with the configuration
    spec = PlannerSpec.of_built(built[1])
    assert spec.kind_source == f"{mod}:KIND" and not reads_recorded_future(spec)
    (tmp_path / "spec.pkl").write_bytes(pickle.dumps(spec))
    code = ("import pickle, sys; from letspi.simulation.spec import build_planner; "
            f"print(build_planner(pickle.load(open({str(tmp_path / 'spec.pkl')!r}, 'rb'))).name)")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(ROOT / "src")])}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "my-cv", out.stderr
    # its version is part of the key: another version under the same label is refused, naming it
    (tmp_path / f"{mod}.py").write_text(PLUGIN.format(version='version: str = "2"', prefix="my_cv_", name="my-cv"))
    monkeypatch.setattr(table_module, "_BY_PATH", {})
    monkeypatch.delitem(sys.modules, mod)
    with pytest.raises(EvaluationDirError, match="version: 1 -> 2"):
        lp.evaluate(lp.planners(f"{mod}:KIND", my_cv_scale=2.0), _batch(), tmp_path / "ev")


@pytest.mark.parametrize(("target", "message"), [
    ("no_such_module_xyz:KIND", "cannot import no_such_module_xyz"),
    ("plugin_bad:MISSING", "has no 'MISSING'"),
    ("plugin_bad:NOT_A_KIND", "is a class, not a letspi PlannerKind"),
    ("plugin_bad", "an import path is package.module:NAME"),
])
def test_import_path_errors_say_what_is_wrong(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, target: str,
                                              message: str) -> None:
    _plugin(tmp_path, monkeypatch, "plugin_bad")
    with pytest.raises(PlannerKindError, match=message):
        load_kind(target if ":" in target else target + ":")


def test_a_kind_must_declare_its_version_prefix_its_options_and_not_take_a_name(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _plugin(tmp_path, monkeypatch, "plugin_noversion", version="")
    with pytest.raises(PlannerKindError, match="has no 'version' field"):
        load_kind("plugin_noversion:KIND")
    _plugin(tmp_path, monkeypatch, "plugin_prefix", prefix="")
    with pytest.raises(PlannerKindError, match="option\\(s\\) scale must start with 'my_cv_'"):
        load_kind("plugin_prefix:KIND")
    _plugin(tmp_path, monkeypatch, "plugin_taken", name="sf", prefix="sf_")
    with pytest.raises(PlannerKindError, match="planner kind 'sf' exists already"):
        load_kind("plugin_taken:KIND")
    result = subprocess.run([sys.executable, "-m", "letspi.cli.app", "evaluate", "--scenarios", "x.arrow",
                             "--planner", "plugin_taken:KIND", "--out", str(tmp_path / "o")],
                            capture_output=True, text=True, cwd=tmp_path, timeout=120,
                            env={**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(ROOT / "src")])})
    assert result.returncode == 2 and "planner kind 'sf' exists already" in result.stderr + result.stdout


def _installed_example(tmp_path: Path) -> dict[str, str]:
    """The environment of a process that has the example package installed: this one's when it is (CI
    installs it), else a pip --target install of examples/letspi-gap-keeper on PYTHONPATH."""
    try:
        importlib.metadata.distribution("letspi-gap-keeper")
        return dict(os.environ)
    except importlib.metadata.PackageNotFoundError:
        target, source = tmp_path / "site", tmp_path / "letspi-gap-keeper"
        shutil.copytree(EXAMPLE, source, ignore=shutil.ignore_patterns("build", "*.egg-info"))  # builds there
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
                        "--target", str(target), str(source)], check=True, timeout=300)
        return {**os.environ, "PYTHONPATH": os.pathsep.join([str(target), os.environ.get("PYTHONPATH", "")])}


LEADERBOARD = '''
import json, sys
from pathlib import Path
import letspi_gap_keeper
from letspi.benchmark.leaderboard import leaderboard, mode_board, to_markdown
from letspi.benchmark.suites import SUITES
from letspi.evaluation.results import load_planner_results
out = Path(sys.argv[1])
frame = load_planner_results(out, "sf")
board = mode_board(out, ["sf", "gap-keeper"], dict(zip(frame.scenario_digest, frame.vehicle_key)), "sf")
print(json.dumps({"module": letspi_gap_keeper.__file__, "board": board,
                  "markdown": to_markdown(leaderboard(SUITES["highway-critical"], {"open-loop": board}, "d"))}))
'''


def test_the_example_package_runs_installed_and_appears_on_a_leaderboard_next_to_sf(tmp_path: Path) -> None:
    env = _installed_example(tmp_path)

    def letspi(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "letspi.cli.app", *args], capture_output=True, text=True,
                              env=env, cwd=tmp_path, timeout=300)

    rows = {row["kind"]: row for row in json.loads(letspi("planners", "--json").stdout)}
    assert rows["gap-keeper"]["source"] == "letspi-gap-keeper 0.1.0" and rows["sf"]["source"] == "built in"
    assert [o["flag"] for o in rows["gap-keeper"]["options"]] == ["--gap-keeper-time-gap-s"]
    scenarios = save_scenarios(_batch(), tmp_path / "s.arrow")
    out = tmp_path / "ev"
    result = letspi("evaluate", "--scenarios", str(scenarios), "--planner", "sf", "--planner", "gap-keeper",
                    "--gap-keeper-time-gap-s", "1.8", "--goals", "kinematic", "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert "| gap-keeper | ↓ CR (%) | 16 |" in result.stdout  # paired with sf
    config = json.loads((out / "per_scenario" / "gap-keeper" / "config.json").read_text())
    assert config["identity"] == {"kind": "gap-keeper", "version": "1", "time_gap_s": 1.8}
    assert letspi("evaluate", "--scenarios", str(scenarios), "--planner", "gap-keeper", "--gap-keeper-time-gap-s",
                  "9", "--out", str(out)).returncode == 2  # its own check of its option
    board = subprocess.run([sys.executable, "-c", LEADERBOARD, str(out)], capture_output=True, text=True, env=env,
                           timeout=300)
    assert board.returncode == 0, board.stderr
    data = json.loads(board.stdout)
    assert EXAMPLE not in Path(data["module"]).parents  # its own installed copy, not the source tree
    assert set(data["board"]["planners"]) == {"sf", "gap-keeper"}
    assert data["board"]["paired"]["planners"]["gap-keeper"]["cr_pct"]["n_pairs"] == 16
    lines = [line for line in data["markdown"].splitlines() if line.startswith(("| sf |", "| gap-keeper |"))]
    assert len(lines) >= 2, data["markdown"]
    assert np.isfinite(json.loads((out / "metrics.json").read_text())["planners"]["gap-keeper"]["ttc_s"])


@pytest.mark.sumo
def test_a_kind_by_import_path_runs_closed_loop_in_a_worker_process(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    mod = _plugin(tmp_path, monkeypatch, "plugin_closed")
    built = lp.planners(f"{mod}:KIND")
    config = lp.ClosedLoopConfig(mode="closed-loop-log", replan_s=1.0, workers=1)
    results = lp.evaluate(built, _batch().take(np.arange(3)), tmp_path / "cl", closed_loop=config)
    assert results.run["mode"] == "closed-loop-log" and len(results.per_scenario("my-cv")) == 3
    record = json.loads((tmp_path / "cl" / "per_scenario" / "my-cv" / "config.json").read_text())
    assert record["identity"]["version"] == "1" and record["evaluation"]["mode"] == "closed-loop-log"
