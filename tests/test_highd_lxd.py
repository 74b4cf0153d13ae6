"""Generated recordings open in the field's own reader, ``lxd-io`` (levelXData: highD, inD, rounD, exiD).

``lxd-io`` infers column types from the first rows (polars); it failed on letspi's files when they
printed floats in shortest form (``0`` in the first rows of ``dhw``, then ``215.032057``). Files now
print 2 decimals, as real HighD does.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest
from lxd_io import Dataset

from letspi.highd.generation import read_generation
from letspi.highd.io import read_recording
from letspi.highd.schema import TRACKS_COLUMNS, TRACKS_INT_COLUMNS, TRACKS_META_COLUMNS, TRACKS_META_INT_COLUMNS


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    pytest.importorskip("sumo")
    from letspi.trafficgen.generate import generate_highd

    root = tmp_path_factory.mktemp("lxd") / "highd-dataset-v1.0"  # the layout lxd-io expects: <root>/data/
    generate_highd(root / "data", minutes=1.0, seed=3, criticality="highd")
    return root


@pytest.mark.sumo
def test_lxd_io_reads_generated_recordings_like_letspi(dataset_dir: Path) -> None:
    dataset = Dataset(dataset_dir)
    assert (dataset.id, dataset.recording_ids) == ("highd", [1])
    theirs = dataset.get_recording(1)
    ours = read_recording(dataset_dir / "data", 1)
    assert sorted(theirs.track_ids) == sorted(ours.tracks_meta["id"].tolist())

    schema = theirs._get_tracks_data().schema  # what polars inferred from the file
    for col in TRACKS_COLUMNS:
        assert schema[col] == (pl.Int64 if col in TRACKS_INT_COLUMNS else pl.Float64), col

    by_id = ours.tracks.groupby("id")
    meta = ours.tracks_meta.set_index("id")
    longest = meta["numFrames"].sort_values(ascending=False).index[:3].tolist()
    with_leader = int(ours.tracks.loc[ours.tracks["precedingId"] > 0, "id"].iloc[0])
    for track_id in [*longest, with_leader]:
        track = theirs.get_track(track_id)
        rows = by_id.get_group(track_id)
        for col in ("frame", "x", "y", "xVelocity", "xAcceleration", "dhw", "thw", "ttc", "precedingId", "laneId"):
            np.testing.assert_array_equal(track.get_data(col), rows[col].to_numpy(), err_msg=f"{track_id} {col}")
        for col in TRACKS_META_COLUMNS:
            want = meta.loc[track_id, col] if col != "id" else track_id
            got = track.get_meta_data(col)
            assert got == want, (track_id, col)
            if col not in TRACKS_META_INT_COLUMNS and col != "class":
                assert isinstance(got, float), (track_id, col)
    assert theirs.get_meta_data("frameRate") == 25
    assert theirs.get_background_image().shape[1] == 1050  # the road drawn at 0.4 m per pixel over 420 m


@pytest.mark.sumo
def test_generated_recordings_print_two_decimals_and_record_their_seed(dataset_dir: Path) -> None:
    lines = (dataset_dir / "data" / "01_tracks.csv").read_text().splitlines()
    header = lines[0].split(",")
    floats = [k for k, c in enumerate(header) if c not in TRACKS_INT_COLUMNS]
    for line in lines[1:200]:
        fields = line.split(",")
        for k in floats:
            whole, dot, frac = fields[k].partition(".")
            assert dot and len(frac) == 2 and whole.lstrip("-").isdigit() and fields[k] != "-0.00", fields[k]
    generation = read_generation(dataset_dir / "data", 1)
    assert generation is not None
    assert (generation["seed"], generation["minutes"], generation["traffic"]["name"]) == (3, 1.0, "highd")
