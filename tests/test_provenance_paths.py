"""Manifests and fitted files record paths without the directories of the machine that wrote them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from letspi.fsutil import provenance_command, provenance_path, provenance_record
from letspi.learned.weights import MANIFEST_FILE, save_weights
from letspi.planners.frenet import FrenetWeights, load_frenet_weights, save_frenet_weights


def test_a_path_below_the_root_stays_relative_and_any_other_keeps_its_name(tmp_path: Path) -> None:
    root = tmp_path / "project"
    assert provenance_path(root / "data" / "train31.arrow", root) == "data/train31.arrow"
    assert provenance_path(tmp_path / "elsewhere" / "train31.arrow", root) == "train31.arrow"
    assert provenance_path(str(root) + "x/y.arrow", root) == "y.arrow"  # a sibling that shares the prefix
    assert provenance_path("runs/labels31", root) == "runs/labels31"  # relative: as typed
    assert provenance_path("/y.arrow", "/") == "y.arrow"  # the file system's root is no project


def test_the_working_directory_is_the_default_root(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert provenance_path(tmp_path / "gen31" / "01_tracks.csv") == "gen31/01_tracks.csv"
    assert provenance_path("/somewhere/else/ft1") == "ft1"


def test_commands_keep_their_words_and_lose_the_directories(monkeypatch: pytest.MonkeyPatch,
                                                            tmp_path: Path) -> None:
    monkeypatch.chdir(tmp_path)
    args = ["train", "llm", "--data", "/runs/model/labels31", "--out=/runs/model/ft 1", "--seed", "31",
            "--note", "a/b"]
    assert provenance_command("letspi", args) == "letspi train llm --data labels31 '--out=ft 1' --seed 31 --note a/b"


def test_a_record_is_rewritten_at_every_depth_and_nothing_else_changes(monkeypatch: pytest.MonkeyPatch,
                                                                         tmp_path: Path) -> None:
    monkeypatch.chdir(tmp_path)
    record = {"sources": [{"labels_dir": "/runs/labels31", "scenarios_path": Path("/data/train31.arrow"),
                           "manifest": {"command": "letspi train llm-data --scenarios /data/train31.arrow --seed 31"},
                           "n": 3, "share": 0.5, "ok": None}],
              "text": "m/s and 1/2, http://host:8080/v1", "odd": "letspi 'unbalanced",
              "note": "letspi data generate --seed 1 (criticality highd; 3+3 lanes) -> --out=/data/gen1 '/a b'"}
    assert provenance_record(record) == {
        "sources": [{"labels_dir": "labels31", "scenarios_path": "train31.arrow",
                     "manifest": {"command": "letspi train llm-data --scenarios train31.arrow --seed 31"},
                     "n": 3, "share": 0.5, "ok": None}],
        "text": "m/s and 1/2, http://host:8080/v1", "odd": "letspi 'unbalanced",
        "note": "letspi data generate --seed 1 (criticality highd; 3+3 lanes) -> --out=gen1 '/a b'"}


def test_a_fitted_file_names_its_scenario_files_only(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path / "..")
    out = tmp_path / "w.json"
    save_frenet_weights(out, FrenetWeights(k_time=0.5), {"scenarios_files": ["/data/train31.arrow",
                                                                            str(tmp_path / "b.arrow")]}, {})
    weights, record = load_frenet_weights(out)
    assert weights == FrenetWeights(k_time=0.5)
    assert record["provenance"]["scenarios_files"] == ["train31.arrow", f"{tmp_path.name}/b.arrow"]


def test_a_model_manifest_names_no_directory(tmp_path: Path) -> None:
    save_weights(tmp_path / "m", {"w": np.ones(2)}, {"data": {"scenario_files": [{"path": Path("/data/t.arrow")}]},
                                                     "training": {"command": "letspi train goals --out /x/m"}})
    manifest = json.loads((tmp_path / "m" / MANIFEST_FILE).read_text())
    assert manifest["data"]["scenario_files"] == [{"path": "t.arrow"}]
    assert manifest["training"]["command"] == "letspi train goals --out m"
