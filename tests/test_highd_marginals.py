"""Traffic marginals against hand-computed values of the sample recording; `data info --compare-highd`."""

from __future__ import annotations

from pathlib import Path

import pytest
from highd_samples import sample_recording
from typer.testing import CliRunner

from letspi.cli.app import app
from letspi.highd.io import write_recording
from letspi.highd.marginals import PUBLISHED_HIGHD, traffic_marginals


def test_marginals_of_the_sample_recording() -> None:
    m = traffic_marginals([sample_recording(1)])
    # 8 vehicles: one truck (3), one lane changer (5, lane 8 -> 7)
    assert m["vehicles"] == 8 and m["truck_share"] == pytest.approx(1 / 8)
    assert m["lane_changer_share"] == pytest.approx(1 / 8) and m["lane_changes_per_vehicle"] == pytest.approx(1 / 8)
    assert m["median_time_in_view_s"] == pytest.approx(50 / 25)  # 50 frames each but vehicle 5 (46)
    assert m["mean_speed_truck_mps"] == pytest.approx(22.0)
    # leftmost lane of each direction: car 4 in lane 6 (33 m/s) and car 12 in lane 4 (30 m/s), 50 rows each
    assert m["mean_speed_lane1_mps"] == pytest.approx(31.5)
    assert 0 < m["thw_median_s"] < 10


def test_compare_highd_prints_generated_beside_published(tmp_path: Path) -> None:
    write_recording(sample_recording(1), tmp_path)
    result = CliRunner().invoke(app, ["data", "info", str(tmp_path), "--compare-highd"])
    assert result.exit_code == 0, result.output
    line = next(x for x in result.output.splitlines() if x.startswith("| lane_changer_share"))
    assert "12.50 %" in line and f"{100 * PUBLISHED_HIGHD['lane_changer_share'].value:.2f} %" in line
    assert "doi 10.1109/ITSC.2018.8569552" in result.output
