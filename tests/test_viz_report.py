"""The HTML report: one row per planner, internal links resolve, images are real, optional sections."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import base64
import io
import json
import re

import pytest
from matplotlib.image import imread
from typer import Typer
from typer.testing import CliRunner

from letspi.assembly.planners import build_planners
from letspi.cli import viz as viz_cli
from letspi.evaluation.harness import EvaluationSettings, evaluate
from letspi.planners.options import PlannerOptions
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.store import save_scenarios
from letspi.scenario.types import concat_batches
from letspi.viz.report import write_report


@pytest.fixture(scope="module")
def eval_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("viz_report")
    batch = concat_batches([
        straight_road_scenario(scenario_id=f"s{i}", neighbours=[VehicleSpec(12.0 + 4 * i, 26.0),
                                                               VehicleSpec(-10.0, 31.0, lane_offset=1)])
        for i in range(3)
    ])
    scen = save_scenarios(batch, root / "scenarios.arrow")
    out = root / "evaluation"
    evaluate(build_planners(["human", "cv"], PlannerOptions()), batch, out,
             EvaluationSettings(scenarios_file=str(scen)))
    return out


def _images(page: str) -> list[str]:
    return re.findall(r'<img src="data:image/png;base64,([^"]+)"', page)


def _check_page(page: str) -> None:
    ids = set(re.findall(r'\sid="([^"]+)"', page))
    hrefs = re.findall(r'href="([^"]*)"', page)
    assert hrefs and all(h.startswith("#") for h in hrefs), "only internal links"
    missing = [h for h in hrefs if h[1:] not in ids]
    assert not missing, f"unresolved anchors: {missing}"
    assert "src=\"http" not in page and "<script" not in page
    for b64 in _images(page):
        pixels = imread(io.BytesIO(base64.b64decode(b64)), format="png")
        assert pixels.shape[0] > 50 and float(pixels[..., :3].var()) > 0.0


def test_report_rows_links_images(eval_dir, tmp_path):
    out = write_report(eval_dir, tmp_path / "r.html", n_worst=1)
    page = out.read_text()
    planners = json.loads((eval_dir / "metrics.json").read_text())["planners"]
    rows = re.findall(r'<tr class="planner-row"><td>(?:<a href="#[^"]+">)?([^<]+)', page)
    assert rows == list(planners)
    _check_page(page)
    # distributions + one worst-scenario diagram per planner
    assert len(_images(page)) == 1 + len(planners)
    assert 'id="worst-human"' in page and 'id="worst-cv"' in page
    assert "draws the plan the evaluation stored" in page and "re-planned" not in page  # what the pictures are
    assert 'id="ablations"' not in page  # no ablation files: section absent, no error


def test_report_ablations_present_and_malformed(eval_dir, tmp_path):
    abl = eval_dir / "ablations"
    abl.mkdir()
    try:
        (abl / "memory_size.json").write_text(json.dumps({"total": 100, "points": [
            {"memory_size": 0, "metrics": {"ttc_s": 3.7, "cr_pct": 9.7}},
            {"memory_size": 80, "metrics": {"ttc_s": 6.0, "cr_pct": 3.4}}]}))
        (abl / "llm_combinations.json").write_text('{"combinations": [{"name": "A"}]}')  # no metrics
        page = write_report(eval_dir, tmp_path / "r.html", with_diagrams=False).read_text()
    finally:
        for f in abl.iterdir():
            f.unlink()
        abl.rmdir()
    _check_page(page)
    assert 'id="ablation-memory-size"' in page
    assert "<td>80</td><td>6.00</td><td>3.40</td>" in page
    assert 'id="ablation-llm-combinations"' in page and "could not read llm_combinations.json" in page
    assert len(_images(page)) == 2  # distributions + memory curve (no diagrams requested)


def test_cli_report_and_plot(eval_dir, tmp_path):
    app = Typer()
    app.command("plot")(viz_cli.plot)
    app.command("report")(viz_cli.report)
    runner = CliRunner()
    res = runner.invoke(app, ["report", str(eval_dir), "--out", str(tmp_path / "x.html"), "--no-diagrams"])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "x.html").exists()
    scen = eval_dir.parent / "scenarios.arrow"
    png = tmp_path / "p.png"
    res = runner.invoke(app, ["plot", "--scenarios", str(scen), "--index", "1", "--planner", "cv", "--out", str(png)])
    assert res.exit_code == 0, res.output
    assert float(imread(png)[..., :3].var()) > 0.0
    res = runner.invoke(app, ["plot", "--scenarios", str(scen), "--index", "9", "--out", str(png)])
    assert res.exit_code == 2
