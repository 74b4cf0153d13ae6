"""Planners on highway-env episodes through one runner: results keyed and resumable, identical across runs, in
worker processes, dual-rate LLM planners (a scripted fake: control flow only), the suites and the command line.
Skipped without the ``highway`` extra."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

pytest.importorskip("highway_env", reason="the highway extra of letspi-interop is not installed")

from letspi.assembly.planners import build_planners
from letspi.benchmark.suites import get_any_suite
from letspi.cli.app import app
from letspi.method.memory import MemoryBank
from letspi.metrics.episode import EPISODE_COLUMNS
from letspi.planners.options import PlannerOptions

pytest.importorskip("letspi_interop", reason="letspi-interop is not installed (pip install -e packages/letspi-interop)")
from letspi_interop.highway_env import suite as he_suites
from letspi_interop.highway_env.run import build_drivers, run_episodes
from letspi_interop.highway_env.settings import EnvSettings
from letspi_interop.highway_env.store import HighwayEnvDirError, load_episodes
from letspi_interop.highway_env.suite import DILU_SEEDS, HighwayEnvSuite
from letspi_interop.highway_env.suite import SUITES as HIGHWAY_ENV_SUITES

#: a cheap scene: 2 lanes, 12 vehicles, 3 s episodes
SMALL = EnvSettings("highway-v0", (("lanes_count", 2), ("vehicles_count", 12), ("ego_spacing", 2)), duration_s=3.0)
PINNED = {
    "highway-env-dilu": "highway-env-dilu@v1-d5241747",
    "highway-env-dilu-5lane-2.5": "highway-env-dilu-5lane-2.5@v1-3ec2df16",
    "highway-env-dilu-5lane-3": "highway-env-dilu-5lane-3@v1-e8bd708a",
    "highway-env-merge": "highway-env-merge@v1-3aceb3e1",
}
runner = CliRunner()


def _answers(frame: pd.DataFrame) -> pd.DataFrame:
    """The per-episode values that must repeat (wall times cannot)."""
    return frame[[c for c in frame if not c.startswith("time_") and not c.startswith("planner_latency")]]


def test_episodes_are_keyed_resumable_and_identical_across_runs(tmp_path: Path) -> None:
    drivers = build_drivers(["sf", "he-idm", "keeper=he-lane-keeper"])
    record = run_episodes(drivers, SMALL, [1, 2], tmp_path / "a", workers=0, reference="sf")
    assert set(record["planners"]) == {"sf", "he-idm", "keeper"} and record["planners"]["sf"]["n"] == 2
    assert set(record["paired"]["planners"]) == {"he-idm", "keeper"}
    assert record["timing"]["sf"]["overhead_pct"] > 0 and record["timing"]["he-idm"]["plan_s"] == 0
    sf = load_episodes(tmp_path / "a", "sf")
    assert list(sf["seed"]) == [1, 2] and set(EPISODE_COLUMNS) <= set(sf.columns)
    assert (sf["time_replans_n"] == 15).all() and sf["planner_latency_s"].notna().all()
    stored = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "a" / "episodes" / "sf").glob("*.parquet")}
    run_episodes(drivers[:1], SMALL, [1, 2, 3], tmp_path / "a", workers=0, reference="sf")  # resumes: seed 3 only
    after = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "a" / "episodes" / "sf").glob("*.parquet")}
    assert set(after) == {"seed-1.parquet", "seed-2.parquet", "seed-3.parquet"}
    assert all(after[name] == mtime for name, mtime in stored.items())
    run_episodes(drivers[:1], SMALL, [1, 2, 3], tmp_path / "b", workers=0)
    pd.testing.assert_frame_equal(_answers(load_episodes(tmp_path / "a", "sf")),
                                  _answers(load_episodes(tmp_path / "b", "sf")))


def test_another_setting_or_configuration_is_refused(tmp_path: Path) -> None:
    run_episodes(build_drivers(["he-idm"]), SMALL, [1], tmp_path, workers=0)
    other = EnvSettings("highway-v0", (("lanes_count", 3), ("vehicles_count", 12), ("ego_spacing", 2)),
                        duration_s=3.0)
    with pytest.raises(HighwayEnvDirError, match=r"environment\.config\.lanes_count: 2 -> 3"):
        run_episodes(build_drivers(["he-idm"]), other, [1], tmp_path, workers=0)
    with pytest.raises(HighwayEnvDirError, match="another configuration"):
        run_episodes(build_drivers(["he-idm=he-lane-keeper"]), SMALL, [1], tmp_path, workers=0)
    with pytest.raises(ValueError, match="reads the recorded future"):
        run_episodes(build_drivers(["human"]), SMALL, [1], tmp_path, workers=0)


@pytest.mark.slow  # two spawned interpreters importing letspi and highway-env: about 20 s
def test_worker_processes_give_the_same_episodes(tmp_path: Path) -> None:
    drivers = build_drivers(["sf"])
    run_episodes(drivers, SMALL, [4, 5], tmp_path / "one", workers=0)
    run_episodes(drivers, SMALL, [4, 5], tmp_path / "two", workers=2)
    for name in ("sf",):
        pd.testing.assert_frame_equal(_answers(load_episodes(tmp_path / "one", name)),
                                      _answers(load_episodes(tmp_path / "two", name)))


def test_llm_planners_run_dual_rate_with_a_fixed_latency(tmp_path: Path) -> None:
    settings = EnvSettings("highway-v0", SMALL.config, duration_s=6.0)  # 2.5 s period, 1.5 s latency (defaults)
    drivers = build_planners(["llm"], PlannerOptions(llm="scripted:default", llm_cache=False))
    run_episodes(drivers, settings, [1], tmp_path, workers=0)
    with np.load(tmp_path / "episodes" / "llm" / "seed-1.npz") as z:
        calls, in_force = z["info_llm_calls"], z["info_llm_in_force"]
    assert len(calls) == 30 and np.flatnonzero(calls).tolist() == [0, 13, 25]  # t = 0, 2.6 s, 5.0 s
    assert np.flatnonzero(in_force)[0] == 8  # 1.5 s = 37.5 frames -> in force from the replan at 1.6 s
    config = json.loads((tmp_path / "episodes" / "llm" / "config.json").read_text())
    assert config["identity"]["evaluation"] == {"mode": "highway-env", "replan_s": 0.2,
                                                "dual_rate": {"llm_period_s": 2.5, "llm_latency_s": 1.5}}


def test_suites_are_pinned_and_refuse_other_versions(monkeypatch) -> None:
    assert {name: s.suite_id for name, s in HIGHWAY_ENV_SUITES.items()} == PINNED
    dilu = HIGHWAY_ENV_SUITES["highway-env-dilu"]
    assert dilu.seeds[:10] == DILU_SEEDS and len(dilu.seeds) == 100 and get_any_suite(dilu.suite_id) is dilu
    assert dict(dilu.config) == {"lanes_count": 4, "vehicles_density": 2, "vehicles_count": 50, "ego_spacing": 4,
                                 "duration": 30, "simulation_frequency": 15}
    assert dict(HIGHWAY_ENV_SUITES["highway-env-dilu-5lane-3"].config)["vehicles_density"] == 3
    with pytest.raises(ValueError, match="is not this letspi's highway-env-dilu"):
        get_any_suite("highway-env-dilu@v1-00000000")
    he_suites.check_versions(dilu)
    monkeypatch.setattr(he_suites, "installed_versions", lambda: {"highway-env": "1.8.2", "gymnasium": "1.4.0"})
    pins = r'highway-env 1\.8\.2 \(the suite pins 1\.12\.1\); pip install -e "packages/letspi-interop\[highway\]"'
    with pytest.raises(ValueError, match=pins):
        he_suites.check_versions(dilu)


def test_command_line_runs_reports_and_exports_an_episode(tmp_path: Path) -> None:
    out = tmp_path / "run"
    args = ["highway-env", "run", "--out", str(out), "--planner", "cv", "--planner", "he-idm", "--seed", "3",
            "--duration-s", "2", "--set", "lanes_count=2", "--set", "vehicles_count=8", "--workers", "0"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "| cv | 1 |" in result.output and "| he-idm | 1 |" in result.output
    result = runner.invoke(app, ["report", str(out)])
    assert result.exit_code == 0 and "<img src='data:image/png;base64," in (out / "report.html").read_text()
    highd = tmp_path / "highd"
    result = runner.invoke(app, ["highway-env", "export", str(out), "--planner", "cv", "--seed", "3", "--out",
                                 str(highd)])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["data", "info", str(highd), "--json"])
    assert result.exit_code == 0 and json.loads(result.output)[str(highd)]["vehicles"] == 9
    result = runner.invoke(app, ["highway-env", "run", "--out", str(tmp_path / "x"), "--env", "parking-v0",
                                 "--planner", "he-idm", "--seed", "1"])
    assert result.exit_code == 2 and "unknown highway-env environment 'parking-v0'" in result.output
    result = runner.invoke(app, ["benchmark", "show", "highway-env-dilu"])
    assert result.exit_code == 0 and "5838, 2421, 7294" in result.output and "highway-env 1.12.1" in result.output


def test_a_suite_run_writes_its_table_report_and_timing(tmp_path: Path) -> None:
    tiny = HighwayEnvSuite(name="tiny", version=1, description="", env_id="highway-v0",
                           config=(("lanes_count", 2), ("vehicles_count", 8)), seeds=(1, 2), published="",
                           sizing="", duration_s=2.0)
    record = he_suites.run_highway_env_suite(tiny, ["sf", "he-idm"], tmp_path, workers=0, log=lambda _m: None)
    assert record["paired"]["reference"] == "sf" and record["planners"]["he-idm"]["n"] == 2
    assert json.loads((tmp_path / "suite.json").read_text())["id"] == tiny.suite_id
    timing = json.loads((tmp_path / "timing.json").read_text())
    assert set(timing["label_s"]) == {"sf", "he-idm"} and timing["workers"] == 0
    assert (tmp_path / "report.html").stat().st_size > 10_000 and "| sf | 2 |" in (tmp_path / "metrics.md").read_text()
    # a later command adds a planner: the table still pairs it with the stored sf
    later = he_suites.run_highway_env_suite(tiny, ["lane-keeper=he-lane-keeper"], tmp_path, workers=0,
                                            reports=False, log=lambda _m: None)
    assert later["paired"]["reference"] == "sf" and {"he-idm", "lane-keeper"} <= set(later["paired"]["planners"])


def test_the_example_external_planner_drives_by_import_path(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "examples" / "letspi-gap-keeper" / "src"))
    record = run_episodes(build_drivers(["letspi_gap_keeper:KIND"]), SMALL, [1], tmp_path, workers=0)
    config = json.loads((tmp_path / "episodes" / "gap-keeper" / "config.json").read_text())
    assert record["planners"]["gap-keeper"]["n"] == 1 and config["kind"] == "gap-keeper"


@pytest.mark.parametrize("suite", sorted(HIGHWAY_ENV_SUITES))
def test_every_built_in_planner_and_the_example_package_drive_every_suite(tmp_path: Path, suite: str,
                                                                          monkeypatch) -> None:
    """One 1-s episode of each suite's environment and configuration per planner (the LLM planners on a scripted
    reply: control flow only). ``human`` replays a recorded future, which an episode does not have; ``mlp``
    ships no weights."""
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "examples" / "letspi-gap-keeper" / "src"))
    s = HIGHWAY_ENV_SUITES[suite]
    settings = EnvSettings(s.env_id, s.config, duration_s=1.0)
    kinds = ["cv", "idm", "sf", "sf-opt", "sf-check", "gnp", "frenet", "llm", "letspi-memory", "letspi-fast",
             "letspi-fs", "letspi_gap_keeper:KIND"]
    with MemoryBank.open(tmp_path / "bank.sqlite"):
        pass  # an empty bank: the fast planners retrieve nothing
    options = PlannerOptions(llm="scripted:default", fast_llm="scripted:default", llm_cache=False,
                             memory=tmp_path / "bank.sqlite")
    drivers = [*build_planners(kinds, options), *build_drivers(["he-idm", "he-lane-keeper"])]
    record = run_episodes(drivers, settings, [s.seeds[0]], tmp_path / "run", workers=0)
    assert sorted(record["planners"]) == sorted(d.name for d in drivers)
    assert all(row["n"] == 1 for row in record["planners"].values())
