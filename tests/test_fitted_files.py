"""Fitted files (sf parameters, frenet weights): one loader and writer, atomic, every error naming the file."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import letspi.fsutil
from letspi.physics.params import SocialForceParams
from letspi.planners.frenet import FrenetWeights, load_frenet_weights, save_frenet_weights
from letspi.planners.sf_params import load_sf_params, save_sf_params


def test_a_fit_round_trips_with_its_provenance(tmp_path: Path) -> None:
    params = SocialForceParams(k_np=21.0)
    path = save_sf_params(tmp_path / "sub" / "sf.json", params, {"n_train": 7}, {"ade_m": 1.5})
    loaded, record = load_sf_params(path)
    assert loaded == params and record["provenance"] == {"n_train": 7} and record["objective"] == {"ade_m": 1.5}
    assert path.read_text() == json.dumps({"params": params.as_dict(), "provenance": {"n_train": 7},
                                           "objective": {"ade_m": 1.5}}, indent=2) + "\n"
    weights = FrenetWeights(k_rss=2.5)
    assert load_frenet_weights(save_frenet_weights(tmp_path / "w.json", weights, {}, {}))[0] == weights


def test_a_failed_write_leaves_the_old_fit_whole(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = save_sf_params(tmp_path / "sf.json", SocialForceParams(k_np=21.0), {}, {})
    before = path.read_bytes()

    def crash(src: object, dst: object) -> None:
        raise OSError("disk gone")

    monkeypatch.setattr(letspi.fsutil.os, "replace", crash)
    with pytest.raises(OSError, match="disk gone"):
        save_sf_params(path, SocialForceParams(k_np=99.0), {}, {})
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["sf.json"]


def test_bad_files_are_named(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"nowhere.json: no such SF parameter file .*letspi fit sf"):
        load_sf_params(tmp_path / "nowhere.json")
    with pytest.raises(FileNotFoundError, match=r"no such frenet weights file .*letspi fit frenet"):
        load_frenet_weights(tmp_path / "nowhere.json")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"params": {"tau_s": 1.0}}))
    with pytest.raises(ValueError, match=r"bad.json: not a valid SF parameter file \(missing parameter"):
        load_sf_params(bad)
    bad.write_text(json.dumps({"weights": {"k_time": -1.0}}))
    with pytest.raises(ValueError, match="bad.json: not a valid frenet weights file"):
        load_frenet_weights(bad)
