"""``letspi export commonroad`` from the command line, with and without letspi-interop and its extra."""

from __future__ import annotations

import importlib.util

from typer.testing import CliRunner

from letspi.cli.app import app
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.store import save_scenarios
from letspi.scenario.types import concat_batches

runner = CliRunner()


def _file(tmp_path):
    batch = concat_batches([straight_road_scenario(neighbours=[VehicleSpec(x0_m=30.0, speed_mps=25.0)],
                                                   scenario_id=f"s{k}") for k in range(3)])
    return save_scenarios(batch, tmp_path / "s.arrow")


def test_export_commonroad_writes_files_or_names_what_is_missing(tmp_path):
    path = _file(tmp_path)
    out = tmp_path / "cr"
    result = runner.invoke(app, ["export", "commonroad", "--scenarios", str(path), "--out", str(out), "--limit", "2"])
    if importlib.util.find_spec("letspi_interop") is None:  # the companion distribution
        assert result.exit_code == 2
        assert "pip install -e packages/letspi-interop" in " ".join(result.output.split())
        assert not out.exists()
    elif importlib.util.find_spec("commonroad") is None:  # its extra
        assert result.exit_code == 2
        assert 'pip install -e "packages/letspi-interop[commonroad]"' in " ".join(result.output.split())
        assert not out.exists()
    else:
        assert result.exit_code == 0, result.output
        assert sorted(p.name for p in out.iterdir()) == ["s0.xml", "s1.xml"]


def test_export_commonroad_refuses_bad_options(tmp_path):
    path = _file(tmp_path)
    args = ["export", "commonroad", "--scenarios", str(path), "--out", str(tmp_path / "cr")]
    if importlib.util.find_spec("commonroad") is None or importlib.util.find_spec("letspi_interop") is None:
        return  # what is missing is reported first (previous test)
    bad_index = runner.invoke(app, [*args, "--index", "7"])
    assert bad_index.exit_code == 2 and "--index 7 outside 0..2" in bad_index.output
    bad_orientation = runner.invoke(app, [*args, "--orientation", "sideways"])
    assert bad_orientation.exit_code == 2 and "heading, axis_aligned" in bad_orientation.output
    planner_only = runner.invoke(app, [*args, "--planner", "frenet"])
    assert planner_only.exit_code == 2 and "give the results directory" in planner_only.output
