"""A researcher's own planner, the first time (docs/your-planner.md): written in a folder of its own, evaluated
next to sf by import path with one of its options, a version bump under a new label, compare, report; without
PYTHONPATH. Each way of getting it wrong ends in one message that names the planner and the fix."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from test_evaluation_statistics import _batch
from typer.testing import CliRunner

import letspi.api as lp
from letspi.assembly import planner_table as table_module
from letspi.assembly.checked import PlannerError
from letspi.cli.app import app
from letspi.scenario.store import save_scenarios

ROOT = Path(__file__).resolve().parents[1]

#: a constant-velocity planner that keeps a time gap: the issue's example, as a user writes it
PLANNER = '''
from dataclasses import dataclass
from typing import Literal

import numpy as np

from letspi.plugin import (DT_S, N_FUTURE, T0_INDEX, Builder, Config, FutureUse, PlanBatch, Planner, PlannerKind,
                           PlannerOption, Resolver, ScenarioBatch)

TIME_GAP = PlannerOption("cv_gap_time_gap_s", float, 1.2, "time gap to the vehicle ahead", unit="s")


@dataclass
class CvGapPlanner:
    time_gap_s: float = 1.2
    name: str = "cv-gap"
    batch_size: int = 4096
    reads_future: bool = False

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        xy0 = batch.ego_xy_m[:, T0_INDEX].astype(np.float64)
        v0 = batch.ego_vxy_mps[:, T0_INDEX].astype(np.float64) / max(self.time_gap_s, 1.0)
        t = DT_S * np.arange(1, N_FUTURE + 1)
        xy = xy0[:, None, :] + v0[:, None, :] * t[None, :, None]
        return PlanBatch(xy_m=xy, vxy_mps=np.broadcast_to(v0[:, None, :], xy.shape).copy(), goals_xy_m=xy[:, -1].copy())


class CvGapConfig(Config):
    kind: Literal["cv-gap"] = "cv-gap"
    version: str = "1"
    time_gap_s: float = 1.2


def resolve(r: Resolver) -> CvGapConfig:
    return CvGapConfig(time_gap_s=float(r.options.get(TIME_GAP)))


def build(b: Builder, c: CvGapConfig, label: str) -> tuple[Planner, float]:
    return CvGapPlanner(time_gap_s=c.time_gap_s, name=label), 0.0


KIND = PlannerKind("cv-gap", "constant velocity keeping a time gap", CvGapConfig, resolve, build,
                   options=(TIME_GAP,), future=FutureUse.NEVER)
'''


def _write_planner(folder: Path, module: str = "cvgap", source: str = PLANNER) -> None:
    (folder / "mypl").mkdir(parents=True, exist_ok=True)
    (folder / "mypl" / "__init__.py").write_text("")
    (folder / "mypl" / f"{module}.py").write_text(source)


def letspi(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """``letspi ARGS`` as the installed command runs it (``-P``: the working directory is not on the path),
    with only letspi's own source on PYTHONPATH (as an install would have it), never the user's folder."""
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "COLUMNS": "200"}
    return subprocess.run([sys.executable, "-P", "-c", "from letspi.cli.app import main; main()", *args], cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=300)


def test_a_new_users_planner_from_its_folder_next_to_sf_bump_compare_report(tmp_path: Path) -> None:
    _write_planner(tmp_path)
    save_scenarios(_batch(), tmp_path / "s.arrow")
    run = ["evaluate", "--scenarios", "s.arrow", "--planner", "sf", "--planner", "mypl.cvgap:KIND",
           "--cv-gap-time-gap-s", "2.0", "--goals", "kinematic", "--out", "runs/mine"]
    first = letspi(tmp_path, *run)
    assert first.returncode == 0, first.stderr
    assert "| cv-gap | ↓ CR (%) | 16 |" in first.stdout  # paired with sf
    config = json.loads((tmp_path / "runs/mine/per_scenario/cv-gap/config.json").read_text())
    assert config["identity"] == {"kind": "cv-gap", "version": "1", "time_gap_s": 2.0}  # its option, in its key
    again = letspi(tmp_path, *run)
    assert again.returncode == 0 and "resumed: sf 16 of 16, cv-gap 16 of 16 windows already stored" in again.stderr
    # a changed planner, its version bumped: refused under the old label, with a command that works
    (tmp_path / "mypl" / "cvgap.py").write_text(PLANNER.replace('version: str = "1"', 'version: str = "2"')
                                                .replace("max(self.time_gap_s, 1.0)", "1.0"))
    refused = letspi(tmp_path, *run)
    message = " ".join(refused.stderr.split())
    assert refused.returncode == 2 and "version: 1 -> 2" in message, refused.stderr
    hint = re.search(r"--planner (\S+=mypl\.cvgap:KIND)\)", message)
    assert hint is not None and hint.group(1) == "cv-gap-v2=mypl.cvgap:KIND", message
    bumped = letspi(tmp_path, *[hint.group(1) if a == "mypl.cvgap:KIND" else a for a in run])
    assert bumped.returncode == 0, bumped.stderr
    compared = letspi(tmp_path, "compare", "runs/mine", "runs/mine", "--reference", "cv-gap", "--out", "runs/cmp")
    assert compared.returncode == 0, compared.stderr
    assert "- cv-gap-v2 (B) vs cv-gap (A): 16 shared windows; configuration A -> B: time_gap_s" not in compared.stdout
    assert "- cv-gap-v2 (B) vs cv-gap (A): 16 shared windows; configuration A -> B: version: 1 -> 2" in compared.stdout
    assert "| cv-gap-v2 vs cv-gap | ↓ CR % | 16 |" in compared.stdout
    reported = letspi(tmp_path, "report", "runs/mine")
    assert reported.returncode == 0, reported.stderr
    page = (tmp_path / "runs/mine/report.html").read_text()
    assert "cv-gap-v2" in page and "cv-gap" in page


@pytest.fixture
def user_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """A user's folder as the working directory, its planners imported fresh (and forgotten afterwards)."""
    monkeypatch.setattr(table_module, "_BY_PATH", {})
    monkeypatch.setattr(sys, "path", list(sys.path))
    monkeypatch.chdir(tmp_path)
    save_scenarios(_batch(), tmp_path / "s.arrow")
    yield tmp_path
    for name in [m for m in sys.modules if m == "mypl" or m.startswith("mypl.")]:
        del sys.modules[name]


def _cli(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, list(args), terminal_width=200)
    return result.exit_code, " ".join(result.output.split())


BROKEN = {
    # a plan() that does not take the batch
    "signature": (("def plan(self, batch: ScenarioBatch) -> PlanBatch:", "def plan(self) -> PlanBatch:"),
                  ["planner 'cv-gap' (import path mypl.broken:KIND)", "CvGapPlanner.plan(self)", "mypl/broken.py:",
                   "cannot be called as plan(batch)", "Define it as `def plan(self, batch: ScenarioBatch)"]),
    # an index error inside plan()
    "index": (("t = DT_S * np.arange(1, N_FUTURE + 1)",
               "t = DT_S * np.arange(1, N_FUTURE + 1) + batch.nbr_xy_m[0, 8, 0, 0]"),
              ["planner 'cv-gap' (import path mypl.broken:KIND): plan() raised IndexError: index 8 is out of bounds "
               "for axis 1 with size 8 (mypl/broken.py:", "in plan)",
               "This is an error in the planner's own code, not in letspi: fix it there"]),
    # a build that returns the planner alone
    "no tuple": (("return CvGapPlanner(time_gap_s=c.time_gap_s, name=label), 0.0",
                  "return CvGapPlanner(time_gap_s=c.time_gap_s, name=label)"),
                 ["planner 'cv-gap' (import path mypl.broken:KIND): build (mypl/broken.py:", "returned a CvGapPlanner, "
                  "not (planner, load_s)", "`return MyPlanner(name=label), 0.0`"]),
    # a configuration whose kind is not the PlannerKind's name
    "kind name": (('kind: Literal["cv-gap"] = "cv-gap"', 'kind: Literal["cvgap"] = "cvgap"'),
                  ["--planner mypl.broken:KIND: the PlannerKind is named 'cv-gap' but its configuration CvGapConfig "
                   "has kind 'cvgap'; give both one name (kind: Literal['cv-gap'] = 'cv-gap')"]),
    # plans of the wrong length
    "shape": (("t = DT_S * np.arange(1, N_FUTURE + 1)", "t = DT_S * np.arange(1, N_FUTURE)"),
              ["planner 'cv-gap' (import path mypl.broken:KIND): CvGapPlanner.plan() returned xy_m of shape (16, 124, "
               "2)", "expected (16, 125, 2)", "Plan 125 steps"]),
}


@pytest.mark.parametrize("variant", list(BROKEN))
def test_a_broken_planner_is_named_with_its_file_and_the_fix(user_folder: Path, variant: str) -> None:
    (old, new), expected = BROKEN[variant]
    assert old in PLANNER
    _write_planner(user_folder, "broken", PLANNER.replace(old, new))
    code, output = _cli("evaluate", "--scenarios", "s.arrow", "--planner", "sf", "--planner", "mypl.broken:KIND",
                        "--goals", "kinematic", "--out", "runs/x")
    assert code == 2, output
    for part in expected:
        assert part in output, (part, output)
    assert "internal error" not in output and "report it" not in output


def test_a_planner_elsewhere_a_mistyped_kind_or_option_name_the_fix(user_folder: Path, tmp_path_factory) -> None:
    _write_planner(user_folder)
    elsewhere = tmp_path_factory.mktemp("elsewhere")
    os.chdir(elsewhere)  # the user runs letspi from another directory (monkeypatch.chdir restores it)
    code, output = _cli("evaluate", "--scenarios", str(user_folder / "s.arrow"), "--planner", "mypl.cvgap:KIND",
                        "--out", "runs/x")
    assert code == 2 and "--planner mypl.cvgap:KIND: cannot import mypl.cvgap" in output
    assert "run letspi in the directory that holds mypl, or add that directory with --planner-path DIR" in output
    code, output = _cli("evaluate", "--scenarios", str(user_folder / "s.arrow"), "--planner", "mypl.cvgap:KIND",
                        "--planner-path", str(user_folder), "--cv-gap-time-gap-s", "1.5", "--goals", "kinematic",
                        "--out", "runs/x")
    assert code == 0, output
    os.chdir(user_folder)
    code, output = _cli("evaluate", "--scenarios", "s.arrow", "--planner", "mypl.cvgap:KND", "--out", "runs/y")
    assert code == 2 and "mypl.cvgap has no 'KND'; did you mean mypl.cvgap:KIND?" in output
    code, output = _cli("evaluate", "--scenarios", "s.arrow", "--planner", "mypl.cvgapp:KIND", "--out", "runs/y")
    assert code == 2 and "package mypl has no module mypl.cvgapp; did you mean mypl.cvgap?" in output
    code, output = _cli("evaluate", "--scenarios", "s.arrow", "--planner", "sff", "--out", "runs/y")
    assert code == 2 and "unknown planner 'sff'; did you mean sf?" in output and "package.module:NAME" in output
    code, output = _cli("evaluate", "--scenarios", "s.arrow", "--planner", "mypl.cvgap:KIND", "--cv-gap-time-gap",
                        "2", "--out", "runs/y")
    assert code == 2 and "No such option: --cv-gap-time-gap" in output and "--cv-gap-time-gap-s" in output


def test_the_api_takes_names_specs_built_planners_and_planner_objects(user_folder: Path) -> None:
    _write_planner(user_folder)
    batch = lp.load_scenarios("s.arrow")
    built = lp.planners("sf", "mypl.cvgap:KIND", neighbours="idm", goals="kinematic", cv_gap_time_gap_s=2.0)
    from mypl.cvgap import CvGapPlanner  # found in the working directory, as the kind was
    assert repr(built[1]) == f"BuiltPlanner(name='cv-gap', kind='cv-gap', key='{built[1].key}', load_s=0)"
    assert len(repr(built)) < 300  # no weight arrays
    results = lp.evaluate(["sf", CvGapPlanner(time_gap_s=2.0, name="mine"), built[1]], batch, "runs/api",
                          goals="kinematic")
    assert results.planners == ["sf", "mine", "cv-gap"] and results.reference == "sf"
    assert repr(results) == "Results('runs/api', planners=['sf', 'mine', 'cv-gap'], reference='sf')"
    record = json.loads(Path("runs/api/per_scenario/mine/config.json").read_text())
    assert record["identity"]["planner_class"] == "mypl.cvgap.CvGapPlanner"
    assert record["identity"]["settings"] == {"time_gap_s": 2.0}
    # an object's settings are in its key: another time gap under the same label is refused
    with pytest.raises(ValueError, match="settings.time_gap_s: 2.0 -> 3.0.*name it 'mine-[0-9a-f]{6}': "
                                         "CvGapPlanner\\(..., name='mine-[0-9a-f]{6}'\\)"):
        lp.evaluate([CvGapPlanner(time_gap_s=3.0, name="mine")], batch, "runs/api")
    plans = lp.plan(CvGapPlanner(), batch.take(np.arange(3)))
    assert plans.xy_m.shape == (3, 125, 2) and lp.plan("cv", batch.take(np.arange(3))).xy_m.shape == (3, 125, 2)
    with pytest.raises(PlannerError, match="plan\\(\\) raised ZeroDivisionError"):
        lp.plan(type("Bad", (), {"name": "bad", "batch_size": 8, "plan": lambda self, b: 1 / 0})(), batch)
    with pytest.raises(ValueError, match="unknown planner option neighbors='idm'; did you mean neighbours"):
        lp.evaluate(["sf"], batch, "runs/api", neighbors="idm")
