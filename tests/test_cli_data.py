"""``letspi data generate`` (presets, --set, speed line) and ``letspi data info --criticality``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from letspi.cli.app import app
from letspi.highd.derive import build_recording
from letspi.highd.events import EVENTS_COLUMNS, write_events
from letspi.highd.io import write_recording
from letspi.scenario.store import read_scenario_meta

runner = CliRunner()


def _closing_pair(directory: Path, gap0_m: float) -> None:
    """Follower at 30 m/s closing on a leader at 20 m/s, 2 s, gap(t) = gap0 - 10 t; plus an events file."""
    t = np.arange(50) * 0.04
    rows = []
    for vid, rear0, v in ((1, 50.0 - 4.5, 30.0), (2, 50.0 + gap0_m, 20.0)):
        rows.append(pd.DataFrame({"frame": np.arange(1, 51), "id": vid, "x": rear0 + v * t, "y": 28.35,
                                  "width": 4.5, "height": 1.8, "xVelocity": v, "yVelocity": 0.0,
                                  "xAcceleration": 0.0, "yAcceleration": 0.0}))
    rec = build_recording(pd.concat(rows, ignore_index=True),
                          pd.DataFrame({"id": [1, 2], "class": "Car", "drivingDirection": 2}), recording_id=1,
                          upper_markings_y_m=(10.0, 13.5, 17.0, 20.5), lower_markings_y_m=(24.0, 27.5, 31.0, 34.5))
    directory.mkdir(parents=True)
    write_recording(rec, directory)
    event = {c: np.nan for c in EVENTS_COLUMNS} | {"frame": 1, "id": 2, "kind": "cut_in", "other_id": 1,
                                                    "lane_id": 7, "target_lane_id": 7}
    write_events(pd.DataFrame([event], columns=list(EVENTS_COLUMNS)), directory, 1)


def test_info_criticality_json_and_side_by_side_table(tmp_path: Path) -> None:
    _closing_pair(tmp_path / "tight", gap0_m=40.0)  # min gap 20.4 m at closing 10 m/s: minTTC 2.04 s
    _closing_pair(tmp_path / "loose", gap0_m=80.0)  # minTTC 6.04 s
    result = runner.invoke(app, ["data", "info", str(tmp_path / "tight"), "--criticality", "--json"])
    assert result.exit_code == 0, result.output
    profile = json.loads(result.output)[str(tmp_path / "tight")]
    assert profile["min_ttc_s"]["median"] == pytest.approx(2.04)
    assert profile["min_ttc_s"]["share_below"] == {"1.5": 0.0, "3": 0.5}
    assert profile["events_by_kind"] == {"cut_in": 1}
    table = runner.invoke(app, ["data", "info", str(tmp_path / "tight"), str(tmp_path / "loose"), "--criticality"])
    assert table.exit_code == 0, table.output
    assert f"| | {tmp_path / 'tight'} | {tmp_path / 'loose'} |" in table.output
    assert "| minTTC < 3 s (share of vehicles) | 50.00 % | 0.00 % |" in table.output


def test_info_criticality_needs_highd_directories(tmp_path: Path) -> None:
    missing = runner.invoke(app, ["data", "info", str(tmp_path), "--criticality"])
    assert missing.exit_code == 2 and "no recordings" in " ".join(missing.output.split()).lower()
    afile = tmp_path / "x.arrow"
    afile.write_bytes(b"")
    result = runner.invoke(app, ["data", "info", str(afile), "--criticality"])
    assert result.exit_code == 2 and "--criticality needs HighD directories" in " ".join(result.output.split())


def test_generate_show_config_applies_preset_and_settings() -> None:
    result = runner.invoke(app, ["data", "generate", "--out", "unused", "--criticality", "stress", "--layout",
                                 "lane_drop", "--set", "events.cut_in_per_min=7", "--show-config"])
    assert result.exit_code == 0, result.output
    cfg = json.loads(result.output)
    assert cfg["name"] == "stress" and cfg["layout"]["kind"] == "lane_drop" and cfg["events"]["cut_in_per_min"] == 7.0
    bad = runner.invoke(app, ["data", "generate", "--out", "unused", "--set", "events.cut_in_per_hour=1"])
    assert bad.exit_code == 2 and "unknown traffic setting 'events.cut_in_per_hour'" in " ".join(bad.output.split())


@pytest.mark.sumo
def test_generate_writes_events_and_prints_speed(tmp_path: Path) -> None:
    pytest.importorskip("sumo")
    out = tmp_path / "highd"
    result = runner.invoke(app, ["data", "generate", "--out", str(out), "--minutes", "0.5", "--seed", "1",
                                 "--lanes-per-direction", "2", "--set", "events.cut_in_per_min=6"])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert "sim-min per wall s" in text and "scripted events" in text
    assert {p.name for p in out.iterdir()} == {"01_tracks.csv", "01_tracksMeta.csv", "01_recordingMeta.csv",
                                               "01_events.csv", "01_highway.png", "01_generation.json"}
    scenarios = tmp_path / "s.arrow"
    result = runner.invoke(app, ["data", "scenarios", "--highd", str(out), "--out", str(scenarios), "--max", "5"])
    assert result.exit_code == 0, result.output
    generation = read_scenario_meta(scenarios)["provenance"]["generation"]  # type: ignore[index]
    assert [(g["recording"], g["seed"], g["traffic"]["events"]["cut_in_per_min"]) for g in generation] == [(1, 1, 6.0)]
