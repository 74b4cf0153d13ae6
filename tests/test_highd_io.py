"""HighD reading/writing: round trips, validation errors that name file/column/line, atomic writes."""

from __future__ import annotations

import pickle
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from highd_samples import LOWER_MARKINGS, UPPER_MARKINGS, sample_recording
from hypothesis import given, settings
from hypothesis import strategies as st

from letspi.highd import io as highd_io
from letspi.highd.derive import build_recording
from letspi.highd.errors import HighDFormatError
from letspi.highd.io import list_recording_ids, read_recording, read_recordings, write_recording
from letspi.highd.schema import (
    RECORDING_META_COLUMNS,
    TRACKS_COLUMNS,
    TRACKS_META_COLUMNS,
    recording_meta_file,
    tracks_file,
    tracks_meta_file,
)
from letspi.highd.types import Recording

TOL = 0.005 + 1e-9  # files keep 2 decimals, as real HighD


@pytest.fixture(scope="module")
def rec() -> Recording:
    return sample_recording(1)


@pytest.fixture
def rec_dir(tmp_path: Path, rec: Recording) -> Path:
    write_recording(rec, tmp_path)
    return tmp_path


def _assert_same(a: Recording, b: Recording) -> None:
    assert a.recording_id == b.recording_id
    for got, want in ((a.tracks, b.tracks), (a.tracks_meta, b.tracks_meta)):
        assert list(got.columns) == list(want.columns)
        assert len(got) == len(want)
        for col in got.columns:
            if want[col].dtype == np.float64:
                np.testing.assert_allclose(got[col].to_numpy(), want[col].to_numpy(), atol=TOL, rtol=0, err_msg=col)
            else:
                assert got[col].tolist() == want[col].tolist(), col
    assert set(a.meta) == set(b.meta) == set(RECORDING_META_COLUMNS)
    for key, want_value in b.meta.items():
        if isinstance(want_value, float):
            assert a.meta[key] == pytest.approx(want_value, abs=TOL), key
        else:
            assert a.meta[key] == want_value, key
            assert type(a.meta[key]) is type(want_value), key


def _edit_line(path: Path, line: int, edit: object) -> None:
    """Replace 1-based ``line`` of ``path`` by ``edit(old_line)``."""
    lines = path.read_text().splitlines(keepends=True)
    lines[line - 1] = edit(lines[line - 1])  # type: ignore[operator]
    path.write_text("".join(lines))


def _set_field(path: Path, line: int, column: str, value: str) -> None:
    header = path.read_text().splitlines()[0].split(",")
    k = header.index(column)

    def edit(old: str) -> str:
        fields = old.rstrip("\n").split(",")
        fields[k] = value
        return ",".join(fields) + "\n"

    _edit_line(path, line, edit)


# ------------------------------------------------------------------------------------------
# round trips and listing
# ------------------------------------------------------------------------------------------


def test_write_read_round_trip(tmp_path: Path, rec: Recording) -> None:
    paths = write_recording(rec, tmp_path)
    assert [p.name for p in paths] == ["01_recordingMeta.csv", "01_tracksMeta.csv", "01_tracks.csv"]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in paths)  # no temp files
    _assert_same(read_recording(tmp_path, 1), rec)


def test_written_files_are_plain_highd(rec_dir: Path) -> None:
    tracks_lines = (rec_dir / "01_tracks.csv").read_text().splitlines()
    assert tracks_lines[0] == ",".join(TRACKS_COLUMNS)
    first = dict(zip(TRACKS_COLUMNS, tracks_lines[1].split(","), strict=True))
    assert first["frame"] == "1" and first["id"] == "1" and first["laneId"] == "7"  # ints as ints
    assert float(first["dhw"]) == 25.5
    meta_lines = (rec_dir / "01_recordingMeta.csv").read_text().splitlines()
    assert meta_lines[0] == ",".join(RECORDING_META_COLUMNS)
    meta = dict(zip(RECORDING_META_COLUMNS, meta_lines[1].split(","), strict=True))
    assert meta["upperLaneMarkings"] == "10.00;13.50;17.00;20.50"
    assert meta["month"] == "09"
    tm_lines = (rec_dir / "01_tracksMeta.csv").read_text().splitlines()
    assert tm_lines[0] == ",".join(TRACKS_META_COLUMNS)
    assert '"' not in tm_lines[1]


def test_read_sorts_tracks_by_id_then_frame(rec_dir: Path, rec: Recording) -> None:
    path = rec_dir / "01_tracks.csv"
    lines = path.read_text().splitlines(keepends=True)
    path.write_text(lines[0] + "".join(reversed(lines[1:])))
    _assert_same(read_recording(rec_dir, 1), rec)


def test_read_accepts_reordered_columns(rec_dir: Path, rec: Recording) -> None:
    path = rec_dir / "01_tracksMeta.csv"
    frame = pd.read_csv(path, dtype=str)
    frame[list(reversed(frame.columns))].to_csv(path, index=False)
    _assert_same(read_recording(rec_dir, 1), rec)


def test_list_and_read_recordings(tmp_path: Path, rec: Recording) -> None:
    write_recording(rec, tmp_path)
    rec3 = sample_recording(3)
    write_recording(rec3, tmp_path)
    (tmp_path / "notes.txt").write_text("not a recording")
    assert list_recording_ids(tmp_path) == [1, 3]
    both = read_recordings(tmp_path)
    assert [r.recording_id for r in both] == [1, 3]
    only = read_recordings(tmp_path, [3])
    assert len(only) == 1
    _assert_same(only[0], rec3)


# ------------------------------------------------------------------------------------------
# bad input: every error names the file and the column and/or line
# ------------------------------------------------------------------------------------------


def _read_error(directory: Path) -> HighDFormatError:
    with pytest.raises(HighDFormatError) as info:
        read_recording(directory, 1)
    return info.value


def test_missing_file(rec_dir: Path) -> None:
    (rec_dir / "01_tracksMeta.csv").unlink()
    err = _read_error(rec_dir)
    assert err.path.name == "01_tracksMeta.csv"
    assert str(err) == "01_tracksMeta.csv: file not found"


def test_missing_column(rec_dir: Path) -> None:
    path = rec_dir / "01_tracks.csv"
    pd.read_csv(path).drop(columns=["xVelocity"]).to_csv(path, index=False)
    err = _read_error(rec_dir)
    assert (err.path.name, err.column, err.line) == ("01_tracks.csv", "xVelocity", None)
    assert "01_tracks.csv" in str(err) and "'xVelocity'" in str(err)


def test_non_numeric_value(rec_dir: Path) -> None:
    _set_field(rec_dir / "01_tracks.csv", 17, "xVelocity", "abc")
    err = _read_error(rec_dir)
    assert str(err) == "01_tracks.csv: column 'xVelocity', line 17: not a number ('abc')"
    assert (err.column, err.line, err.row) == ("xVelocity", 17, 17)


@pytest.mark.parametrize(
    ("column", "value", "reason"),
    [
        ("laneId", "abc", "not a number ('abc')"),
        ("laneId", "7.5", "not an integer ('7.5')"),
        ("precedingId", "1e30", "not an integer ('1e30')"),
        ("x", "", "empty value"),
        ("ttc", "nan", "not a finite number ('nan')"),
        ("dhw", "inf", "not a finite number ('inf')"),
    ],
)
def test_bad_cells_are_located(rec_dir: Path, column: str, value: str, reason: str) -> None:
    _set_field(rec_dir / "01_tracks.csv", 230, column, value)
    err = _read_error(rec_dir)
    assert str(err) == f"01_tracks.csv: column '{column}', line 230: {reason}"


def test_integral_float_text_in_int_column_is_accepted(rec_dir: Path) -> None:
    _set_field(rec_dir / "01_tracks.csv", 2, "laneId", "7.0")
    tracks = read_recording(rec_dir, 1).tracks
    assert tracks["laneId"].dtype == np.int64 and tracks["laneId"].iloc[0] == 7


def test_bad_cell_line_counts_blank_lines(rec_dir: Path) -> None:
    # pandas skips blank lines; the reported line must still be the file's line number
    path = rec_dir / "01_tracks.csv"
    _edit_line(path, 5, lambda old: old + "\n\n")
    _set_field(path, 12, "y", "oops")
    assert str(_read_error(rec_dir)) == "01_tracks.csv: column 'y', line 12: not a number ('oops')"


def test_id_in_tracks_missing_from_meta(rec_dir: Path) -> None:
    path = rec_dir / "01_tracksMeta.csv"
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(line for line in lines if not line.startswith("4,")))
    err = _read_error(rec_dir)
    # vehicle 4 (ids 1, 2, 3 have 50 rows each before it) starts on line 2 + 150
    assert str(err) == "01_tracks.csv: column 'id', line 152: vehicle id 4 is not in 01_tracksMeta.csv"


@pytest.mark.parametrize("name", ["01_tracks.csv", "01_tracksMeta.csv", "01_recordingMeta.csv"])
def test_empty_file(rec_dir: Path, name: str) -> None:
    (rec_dir / name).write_text("")
    err = _read_error(rec_dir)
    assert str(err) == f"{name}: empty file (no header)"


@pytest.mark.parametrize("name", ["01_tracks.csv", "01_tracksMeta.csv", "01_recordingMeta.csv"])
def test_header_only(rec_dir: Path, name: str) -> None:
    path = rec_dir / name
    path.write_text(path.read_text().splitlines()[0] + "\n")
    assert str(_read_error(rec_dir)) == f"{name}: no data rows (header only)"


def test_truncated_last_line(rec_dir: Path) -> None:
    path = rec_dir / "01_tracks.csv"
    text = path.read_text()
    n_lines = text.count("\n")
    path.write_text(text[: len(text) - 40])  # cut the last line in the middle
    err = _read_error(rec_dir)
    assert err.path.name == "01_tracks.csv" and err.line == n_lines
    assert str(err).startswith(f"01_tracks.csv: line {n_lines}: expected 25 fields, found ")


@pytest.mark.parametrize(
    ("name", "line", "n_fields"),
    [("01_tracksMeta.csv", 2, 16), ("01_tracksMeta.csv", 5, 16), ("01_tracks.csv", 40, 25)],
)
def test_extra_field(rec_dir: Path, name: str, line: int, n_fields: int) -> None:
    _edit_line(rec_dir / name, line, lambda old: old.rstrip("\n") + ",99\n")
    err = _read_error(rec_dir)
    assert (
        str(err)
        == f"{name}: line {line}: expected {n_fields} fields, found {n_fields + 1} (truncated or malformed line)"
    )


@pytest.mark.parametrize(("value", "reason"), [("", "empty value"), ("NA", "missing value ('NA')")])
def test_missing_class(rec_dir: Path, value: str, reason: str) -> None:
    _set_field(rec_dir / "01_tracksMeta.csv", 5, "class", value)
    assert str(_read_error(rec_dir)) == f"01_tracksMeta.csv: column 'class', line 5: {reason}"


def test_unknown_class(rec_dir: Path) -> None:
    _set_field(rec_dir / "01_tracksMeta.csv", 3, "class", "Bus")
    err = _read_error(rec_dir)
    assert (err.path.name, err.column, err.line) == ("01_tracksMeta.csv", "class", 3)
    assert "'Bus'" in str(err)


def test_bad_driving_direction(rec_dir: Path) -> None:
    _set_field(rec_dir / "01_tracksMeta.csv", 4, "drivingDirection", "3")
    err = _read_error(rec_dir)
    assert str(err) == "01_tracksMeta.csv: column 'drivingDirection', line 4: drivingDirection must be 1 or 2, got 3"


def test_frame_gap(rec_dir: Path) -> None:
    path = rec_dir / "01_tracks.csv"
    lines = path.read_text().splitlines(keepends=True)
    del lines[10]  # line 11 = vehicle 1, frame 10
    path.write_text("".join(lines))
    err = _read_error(rec_dir)
    # the row after the gap (frame 11) now sits on line 11
    assert str(err) == (
        "01_tracks.csv: column 'frame', line 11: frame 11 of vehicle 1 follows frame 9 "
        "(frames per vehicle must be consecutive)"
    )


def test_duplicate_frame(rec_dir: Path) -> None:
    path = rec_dir / "01_tracks.csv"
    lines = path.read_text().splitlines(keepends=True)
    lines.insert(11, lines[10])
    path.write_text("".join(lines))
    err = _read_error(rec_dir)
    assert (err.column, err.line) == ("frame", 12) and "repeats" in str(err)


def test_meta_frames_inconsistent_with_tracks(rec_dir: Path) -> None:
    _set_field(rec_dir / "01_tracksMeta.csv", 6, "initialFrame", "6")  # vehicle 5 starts at frame 5
    err = _read_error(rec_dir)
    assert (err.path.name, err.column, err.line) == ("01_tracksMeta.csv", "numFrames", 6)
    _set_field(rec_dir / "01_tracksMeta.csv", 6, "numFrames", "45")
    err = _read_error(rec_dir)
    assert (
        str(err)
        == "01_tracksMeta.csv: column 'initialFrame', line 6: vehicle 5: initialFrame is 6 but 01_tracks.csv has 5"
    )


def test_recording_id_must_match_file_name(rec_dir: Path) -> None:
    _set_field(rec_dir / "01_recordingMeta.csv", 2, "id", "7")
    err = _read_error(rec_dir)
    assert (err.path.name, err.column, err.line) == ("01_recordingMeta.csv", "id", 2)


# ------------------------------------------------------------------------------------------
# atomic, validated writes
# ------------------------------------------------------------------------------------------


def _snapshot(directory: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(directory.iterdir())}


def test_invalid_recording_writes_nothing(rec_dir: Path, rec: Recording) -> None:
    before = _snapshot(rec_dir)
    tm = rec.tracks_meta.copy()
    tm.loc[2, "class"] = "Bus"
    bad = replace(rec, tracks_meta=tm, tracks=rec.tracks.assign(x=rec.tracks["x"] + 1.0))
    with pytest.raises(HighDFormatError) as info:
        write_recording(bad, rec_dir)
    assert (info.value.path.name, info.value.column, info.value.line) == ("01_tracksMeta.csv", "class", 4)
    assert _snapshot(rec_dir) == before


def test_invalid_value_in_memory_names_column_and_line(tmp_path: Path, rec: Recording) -> None:
    tracks = rec.tracks.copy()
    tracks["xVelocity"] = tracks["xVelocity"].astype(object)
    tracks.loc[15, "xVelocity"] = "abc"
    with pytest.raises(HighDFormatError) as info:
        write_recording(replace(rec, tracks=tracks), tmp_path)
    assert str(info.value) == "01_tracks.csv: column 'xVelocity', line 17: not a finite number ('abc')"
    assert list(tmp_path.iterdir()) == []


def test_failure_during_write_leaves_no_partial_files(
    rec_dir: Path, rec: Recording, monkeypatch: pytest.MonkeyPatch
) -> None:
    before = _snapshot(rec_dir)
    real = highd_io._write_csv
    calls = []

    def failing(frame: pd.DataFrame, fh: object) -> None:
        calls.append(1)
        if len(calls) == 3:  # the tracks file, after both meta files were written
            raise OSError("disk full")
        real(frame, fh)  # type: ignore[arg-type]

    monkeypatch.setattr(highd_io, "_write_csv", failing)
    changed = replace(rec, tracks=rec.tracks.assign(x=rec.tracks["x"] + 1.0))
    with pytest.raises(OSError, match="disk full"):
        write_recording(changed, rec_dir)
    assert _snapshot(rec_dir) == before


def test_missing_meta_key_is_reported(tmp_path: Path, rec: Recording) -> None:
    meta = dict(rec.meta)
    del meta["weekDay"]
    with pytest.raises(HighDFormatError) as info:
        write_recording(replace(rec, meta=meta), tmp_path)
    assert (info.value.path.name, info.value.column) == ("01_recordingMeta.csv", "weekDay")


def test_file_names() -> None:
    assert (tracks_file(1), tracks_meta_file(1), recording_meta_file(12)) == (
        "01_tracks.csv",
        "01_tracksMeta.csv",
        "12_recordingMeta.csv",
    )


# ------------------------------------------------------------------------------------------
# property: any built recording survives write -> read
# ------------------------------------------------------------------------------------------

_vehicle = st.tuples(
    st.sampled_from([1, 2]),  # drivingDirection
    st.integers(0, 2),  # lane index within the carriageway
    st.floats(0.0, 400.0),  # x at first frame
    st.floats(5.0, 45.0),  # speed
    st.integers(1, 30),  # first frame
    st.integers(1, 40),  # number of frames
    st.booleans(),  # truck
)


@settings(max_examples=15, deadline=None)
@given(vehicles=st.lists(_vehicle, min_size=1, max_size=6), rid=st.integers(1, 99))
def test_round_trip_property(vehicles: list[tuple], rid: int) -> None:
    rows, meta = [], []
    for vid, (direction, lane, x0, speed, first, n, truck) in enumerate(vehicles, start=1):
        length, width = (15.0, 2.5) if truck else (4.5, 1.8)
        centre = (LOWER_MARKINGS if direction == 2 else UPPER_MARKINGS)[lane] + 1.75
        vx = speed if direction == 2 else -speed
        k = np.arange(n)
        rows.append(
            pd.DataFrame(
                {
                    "frame": first + k,
                    "id": vid,
                    "x": x0 + vx * k / 25.0,
                    "y": centre - width / 2,
                    "width": length,
                    "height": width,
                    "xVelocity": vx,
                    "yVelocity": 0.0,
                    "xAcceleration": 0.0,
                    "yAcceleration": 0.0,
                }
            )
        )
        meta.append({"id": vid, "class": "Truck" if truck else "Car", "drivingDirection": direction})
    rec = build_recording(
        pd.concat(rows, ignore_index=True),
        pd.DataFrame(meta),
        recording_id=rid,
        upper_markings_y_m=UPPER_MARKINGS,
        lower_markings_y_m=LOWER_MARKINGS,
    )
    with tempfile.TemporaryDirectory() as tmp:
        write_recording(rec, Path(tmp))
        _assert_same(read_recording(Path(tmp), rid), rec)


def test_unknown_extra_column_is_ignored(rec_dir: Path, rec: Recording) -> None:
    path = rec_dir / "01_tracksMeta.csv"
    frame = pd.read_csv(path, dtype=str)
    frame.insert(3, "comment", "x")
    frame.to_csv(path, index=False)
    _assert_same(read_recording(rec_dir, 1), rec)


def test_short_line_in_the_middle(rec_dir: Path) -> None:
    _edit_line(rec_dir / "01_tracks.csv", 100, lambda old: ",".join(old.split(",")[:10]) + "\n")
    err = _read_error(rec_dir)
    assert str(err) == "01_tracks.csv: line 100: expected 25 fields, found 10 (truncated or malformed line)"


def test_error_attributes_and_pickling() -> None:
    err = HighDFormatError("/data/01_tracks.csv", "not a number ('abc')", column="xVelocity", row=17)
    assert (err.path, err.column, err.line, err.row) == (Path("/data/01_tracks.csv"), "xVelocity", 17, 17)
    assert isinstance(err, ValueError)
    again = pickle.loads(pickle.dumps(err))
    assert str(again) == str(err) == "01_tracks.csv: column 'xVelocity', line 17: not a number ('abc')"
    assert str(HighDFormatError("x/01_tracks.csv", "bad", line=3)) == "01_tracks.csv: line 3: bad"


def test_not_utf8(rec_dir: Path) -> None:
    path = rec_dir / "01_tracks.csv"
    path.write_bytes(path.read_bytes()[:5000] + b"\xff\xfe" + path.read_bytes()[5000:])
    err = _read_error(rec_dir)
    assert err.path.name == "01_tracks.csv" and "UTF-8" in str(err)


# ------------------------------------------------------------------------------------------
# value and cross-file checks (more cases in test_highd_io_fuzz.py)
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "line", "column", "value", "message"),
    [
        ("01_tracks.csv", 2, "precedingId", "99999999999999999999",
         "01_tracks.csv: column 'precedingId', line 2: not an integer ('99999999999999999999')"),
        ("01_tracks.csv", 2, "width", "-4.5",
         "01_tracks.csv: column 'width', line 2: vehicle 1: width must be positive, got -4.5"),
        ("01_tracksMeta.csv", 3, "height", "0",
         "01_tracksMeta.csv: column 'height', line 3: vehicle 2: height must be positive, got 0"),
        ("01_tracksMeta.csv", 4, "height", "2.2",
         "01_tracksMeta.csv: column 'height', line 4: vehicle 3: height is 2.2 but 01_tracks.csv has 2.5"),
        ("01_tracks.csv", 20, "width", "5.5",
         "01_tracks.csv: column 'width', line 20: vehicle 1: width 5.5 differs from 4.5 in 01_tracksMeta.csv"),
        ("01_tracks.csv", 30, "laneId", "99",
         "01_tracks.csv: column 'laneId', line 30: laneId 99 does not exist on this road (lanes 1..9 from 8 markings)"),
        ("01_tracks.csv", 30, "laneId", "3",
         "01_tracks.csv: column 'laneId', line 30: "
         "vehicle 1 (drivingDirection 2) is in lane 3 of the upper carriageway"),
        ("01_tracks.csv", 30, "precedingId", "55",
         "01_tracks.csv: column 'precedingId', line 30: "
         "precedingId 55 is neither 0 nor a vehicle of 01_tracksMeta.csv"),
        ("01_tracks.csv", 30, "followingId", "1",
         "01_tracks.csv: column 'followingId', line 30: vehicle 1 is its own followingId"),
        ("01_recordingMeta.csv", 2, "numVehicles", "9",
         "01_recordingMeta.csv: column 'numVehicles', line 2: numVehicles is 9 but 01_tracksMeta.csv has 8 vehicles"),
        ("01_recordingMeta.csv", 2, "lowerLaneMarkings", "24.00;inf",
         "01_recordingMeta.csv: column 'lowerLaneMarkings', line 2: markings must be finite numbers ('24.00;inf')"),
        ("01_recordingMeta.csv", 2, "lowerLaneMarkings", "24.00",
         "01_recordingMeta.csv: column 'lowerLaneMarkings', line 2: needs at least 2 markings (the road edges), got 1"),
        ("01_recordingMeta.csv", 2, "speedLimit", "-5",
         "01_recordingMeta.csv: column 'speedLimit', line 2: speedLimit must be -1 (none) or positive, got -5"),
    ],
)
def test_value_and_consistency_errors(
    rec_dir: Path, name: str, line: int, column: str, value: str, message: str
) -> None:
    _set_field(rec_dir / name, line, column, value)
    assert str(_read_error(rec_dir)) == message


def test_frames_start_at_one(rec_dir: Path) -> None:
    _set_field(rec_dir / "01_tracksMeta.csv", 2, "initialFrame", "0")
    _set_field(rec_dir / "01_tracksMeta.csv", 2, "numFrames", "51")
    assert str(_read_error(rec_dir)) == (
        "01_tracksMeta.csv: column 'initialFrame', line 2: vehicle 1: frames start at 1, got initialFrame 0"
    )


def test_invalid_lane_in_memory_writes_nothing(tmp_path: Path, rec: Recording) -> None:
    tracks = rec.tracks.copy()
    tracks.loc[7, "laneId"] = 120  # would wrap around in the int8 lane arrays of scenarios
    with pytest.raises(HighDFormatError) as info:
        write_recording(replace(rec, tracks=tracks), tmp_path)
    assert (info.value.path.name, info.value.column, info.value.line) == ("01_tracks.csv", "laneId", 9)
    assert list(tmp_path.iterdir()) == []


def test_floats_are_written_with_two_decimals_like_real_highd(tmp_path: Path, rec: Recording) -> None:
    tracks = rec.tracks.copy()
    tracks.loc[0, "xAcceleration"] = -0.004  # rounds to zero: no "-0.00"
    tracks.loc[1, "xAcceleration"] = -1.0
    tracks.loc[2, "xAcceleration"] = 215.032057
    write_recording(replace(rec, tracks=tracks), tmp_path)
    lines = (tmp_path / tracks_file(1)).read_text().splitlines()
    column = lines[0].split(",").index("xAcceleration")
    assert [line.split(",")[column] for line in lines[1:4]] == ["0.00", "-1.00", "215.03"]
    meta_line = (tmp_path / "01_recordingMeta.csv").read_text().splitlines()[1].split(",")
    assert len(meta_line[RECORDING_META_COLUMNS.index("speedLimit")].split(".")[1]) == 2


def test_generation_record_round_trip_and_errors(tmp_path: Path) -> None:
    from letspi.highd.generation import generation_file, read_generation, write_generation

    assert read_generation(tmp_path, 1) is None
    write_generation({"seed": 1003, "minutes": 2.0}, tmp_path, 1)
    assert read_generation(tmp_path, 1) == {"seed": 1003, "minutes": 2.0}
    with pytest.raises(ValueError, match="integer 'seed'"):
        write_generation({"seed": "x"}, tmp_path, 2)
    (tmp_path / generation_file(3)).write_text("{not json")
    with pytest.raises(ValueError, match="03_generation.json: not valid JSON"):
        read_generation(tmp_path, 3)
