"""Corrupted HighD recordings (issue 15): every one is a ``HighDFormatError`` naming the file (and the
column and/or line where there is one), never a pandas/numpy traceback, never partial output.

Two parts:

* a catalogue of > 250 deliberate corruptions of a valid recording (missing/duplicated columns,
  extra/missing fields, bad types, NaN/inf, negative sizes, non-monotonic or duplicate frames,
  duplicate ids, unknown lane and vehicle ids, truncated/empty/binary files, meta that contradicts
  the tracks), each with the file the error must name;
* hypothesis byte-level damage (truncation, flipped/zeroed/inserted bytes) of each file: the reader
  either raises ``HighDFormatError`` naming that file, or returns a recording that passes its own
  validation.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from fuzz_settings import fuzz
from highd_samples import sample_recording
from hypothesis import given
from hypothesis import strategies as st

from letspi.highd.errors import HighDFormatError
from letspi.highd.io import read_recording, validate_recording, write_recording
from letspi.highd.schema import (
    RECORDING_META_COLUMNS,
    RECORDING_META_STR_COLUMNS,
    TRACKS_COLUMNS,
    TRACKS_INT_COLUMNS,
    TRACKS_META_COLUMNS,
    TRACKS_META_INT_COLUMNS,
    TRACKS_META_STR_COLUMNS,
)

RM, TM, TR = "01_recordingMeta.csv", "01_tracksMeta.csv", "01_tracks.csv"
COLUMNS = {RM: RECORDING_META_COLUMNS, TM: TRACKS_META_COLUMNS, TR: TRACKS_COLUMNS}
INTS = {RM: frozenset({"id", "frameRate", "locationId", "numVehicles", "numCars", "numTrucks"}),
        TM: TRACKS_META_INT_COLUMNS, TR: TRACKS_INT_COLUMNS}
STRS = {RM: RECORDING_META_STR_COLUMNS, TM: TRACKS_META_STR_COLUMNS, TR: frozenset()}
Files = dict[str, bytes]


@dataclass(frozen=True)
class Case:
    """One corruption: ``edit`` maps the three files' bytes to new bytes; ``file`` is the file the
    error must name (None: any of the three); ``located``: the error must name a column or a line."""

    name: str
    edit: Callable[[Files], Files]
    file: str | None
    located: bool = True
    column: str | None = None  # the column the error must name, if given


# --- text helpers ------------------------------------------------------------------------------


def _lines(data: bytes) -> list[str]:
    return data.decode().splitlines(keepends=True)


def set_field(name: str, line: int, column: str, value: str) -> Callable[[Files], Files]:
    def edit(files: Files) -> Files:
        lines = _lines(files[name])
        k = lines[0].rstrip("\n").split(",").index(column)
        fields = lines[line - 1].rstrip("\n").split(",")
        fields[k] = value
        lines[line - 1] = ",".join(fields) + "\n"
        return {**files, name: "".join(lines).encode()}

    return edit


def map_column(name: str, column: str, fn: Callable[[str], str], rows: slice = slice(None)) -> Callable[[Files], Files]:
    """Apply ``fn`` to ``column`` in the data rows ``rows`` (0-based, after the header)."""

    def edit(files: Files) -> Files:
        lines = _lines(files[name])
        k = lines[0].rstrip("\n").split(",").index(column)
        body = lines[1:]
        for i in range(len(body))[rows]:
            fields = body[i].rstrip("\n").split(",")
            fields[k] = fn(fields[k])
            body[i] = ",".join(fields) + "\n"
        return {**files, name: "".join([lines[0], *body]).encode()}

    return edit


def drop_column(name: str, column: str) -> Callable[[Files], Files]:
    def edit(files: Files) -> Files:
        lines = _lines(files[name])
        k = lines[0].rstrip("\n").split(",").index(column)
        out = []
        for line in lines:
            fields = line.rstrip("\n").split(",")
            del fields[k]
            out.append(",".join(fields) + "\n")
        return {**files, name: "".join(out).encode()}

    return edit


def rename_column(name: str, column: str, new: str) -> Callable[[Files], Files]:
    def edit(files: Files) -> Files:
        lines = _lines(files[name])
        header = lines[0].rstrip("\n").split(",")
        header[header.index(column)] = new
        return {**files, name: (",".join(header) + "\n" + "".join(lines[1:])).encode()}

    return edit


def edit_lines(name: str, fn: Callable[[list[str]], list[str]]) -> Callable[[Files], Files]:
    def edit(files: Files) -> Files:
        return {**files, name: "".join(fn(_lines(files[name]))).encode()}

    return edit


def replace_bytes(name: str, fn: Callable[[bytes], bytes]) -> Callable[[Files], Files]:
    def edit(files: Files) -> Files:
        return {**files, name: fn(files[name])}

    return edit


def truncate(data: bytes, frac: float) -> bytes:
    """Cut ``data`` just after a comma near ``frac`` of its length (a line with too few fields)."""
    k = int(len(data) * frac)
    after = data.find(b",", k)
    return data[: (after if after >= 0 else data.rfind(b",")) + 1]


# --- the catalogue ---------------------------------------------------------------------------------


def _bad_values(name: str, column: str) -> list[str]:
    if column in STRS[name]:
        return ["", "NA"] if column != "class" else ["", "Bus", "car"]
    values = ["abc", "", "nan", "inf", "-inf", "1e400", "0x1F", "NULL"]
    if column in INTS[name]:
        values = ["7.5", "1e30", "99999999999999999999", *values]
    return values


def catalogue() -> list[Case]:
    cases: list[Case] = []
    for name, columns in COLUMNS.items():
        for column in columns:
            cases.append(Case(f"missing column {name}:{column}", drop_column(name, column), name, column=column))
        cases.append(Case(f"duplicated column {name}", rename_column(name, columns[1], columns[0]), name))
        for line in (2, 3) if name != RM else (2,):
            cases.append(Case(f"extra field {name}:{line}", edit_lines(name, lambda ls, i=line: [
                *ls[: i - 1], ls[i - 1].rstrip("\n") + ",99\n", *ls[i:]]), name))
            cases.append(Case(f"missing field {name}:{line}", edit_lines(name, lambda ls, i=line: [
                *ls[: i - 1], ls[i - 1].rsplit(",", 1)[0] + "\n", *ls[i:]]), name))
        # every column, three bad values each (types, NaN, infinities, overflow), rotating through the pool
        for i, column in enumerate(columns):
            pool = _bad_values(name, column)
            for value in sorted({pool[(i + j) % len(pool)] for j in range(3)}):
                line = 2 if name == RM else 3
                cases.append(Case(f"bad value {name}:{column}={value!r}", set_field(name, line, column, value), name,
                                  column=column))
        cases.append(Case(f"empty file {name}", replace_bytes(name, lambda b: b""), name, located=False))
        cases.append(Case(f"blank file {name}", replace_bytes(name, lambda b: b"\n\n  \n"), name, located=False))
        cases.append(Case(f"header only {name}", edit_lines(name, lambda ls: ls[:1]), name, located=False))
        cases.append(Case(f"binary {name}", replace_bytes(name, lambda b: bytes(range(256)) * 4), name, located=False))
        cases.append(Case(f"NUL bytes {name}", replace_bytes(name, lambda b: b.replace(b",", b"\x00,", 3)), name))
        cases.append(Case(f"not UTF-8 {name}", replace_bytes(name, lambda b: b[:40] + b"\xff\xfe" + b[40:]), name,
                          located=False))
        for frac in (0.13, 0.5, 0.77, 0.999):  # truncated in the middle of a line, after a comma
            cases.append(Case(f"truncated {name} at {frac}", replace_bytes(name, lambda b, f=frac: truncate(b, f)),
                              name))
    # negative and zero sizes
    for name in (TR, TM):
        for column in ("width", "height"):
            for value in ("-4.5", "0", "-0.0"):
                cases.append(Case(f"size {name}:{column}={value}", map_column(name, column, lambda v, x=value: x,
                                                                            slice(0, 1)), name))
    # sizes that contradict tracksMeta
    cases.append(Case("tracks width differs from meta", map_column(TR, "width", lambda v: "5.5", slice(3, 4)), TR))
    cases.append(Case("meta height differs from tracks", set_field(TM, 4, "height", "2.2"), TM))
    # frames: non-monotonic, repeated, gaps, non-positive
    cases.append(Case("frame repeated", map_column(TR, "frame", lambda v: str(int(v) - 1), slice(5, 6)), TR))
    cases.append(Case("frame jumps", map_column(TR, "frame", lambda v: str(int(v) + 3), slice(5, 6)), TR))
    # (the reader sorts rows by (id, frame): reversed frames of vehicle 1 now start at 50, not 1)
    cases.append(Case("frames decrease", map_column(TR, "frame", lambda v: str(100 - int(v)), slice(0, 50)), TM))
    cases.append(Case("duplicate row", edit_lines(TR, lambda ls: [*ls[:8], ls[7], *ls[8:]]), TR))
    cases.append(Case("frame zero", map_column(TR, "frame", lambda v: str(int(v) - 1), slice(0, 50)), None))
    cases.append(Case("negative frames", map_column(TR, "frame", lambda v: str(int(v) - 100), slice(0, 50)), None))
    # ids
    cases.append(Case("duplicate id in meta", edit_lines(TM, lambda ls: [*ls, ls[1]]), TM))
    cases.append(Case("id renamed in meta", set_field(TM, 3, "id", "1"), TM))
    cases.append(Case("vehicle id 0", map_column(TR, "id", lambda v: "0", slice(0, 50)), TR))
    cases.append(Case("negative vehicle id", set_field(TM, 2, "id", "-1"), None))
    cases.append(Case("unknown vehicle in tracks", map_column(TR, "id", lambda v: "77", slice(0, 50)), TR))
    cases.append(Case("vehicle missing from tracks", edit_lines(TR, lambda ls: [ls[0], *ls[51:]]), TM))
    for column in ("precedingId", "followingId", "leftAlongsideId", "rightFollowingId"):
        cases.append(Case(f"unknown neighbour {column}", set_field(TR, 10, column, "55"), TR))
        cases.append(Case(f"negative neighbour {column}", set_field(TR, 10, column, "-2"), TR))
    # lanes (3+3 road: 8 markings, laneId 1..9 possible, lanes 2-4 and 6-8 real)
    for value in ("0", "-1", "10", "99", "127", "128", "200", "-129"):
        cases.append(Case(f"unknown laneId {value}", set_field(TR, 12, "laneId", value), TR))
    cases.append(Case("lower vehicle on the upper carriageway",
                      map_column(TR, "laneId", lambda v: "3", slice(0, 50)), TR))
    cases.append(Case("upper vehicle on the lower carriageway",
                      map_column(TR, "laneId", lambda v: "7", slice(-50, None)), TR))
    # meta that contradicts the other files
    cases.append(Case("recording id vs file name", set_field(RM, 2, "id", "7"), RM))
    for column, value in (("numVehicles", "9"), ("numVehicles", "0"), ("numCars", "1"), ("numTrucks", "0"),
                          ("frameRate", "0"), ("frameRate", "-25")):
        cases.append(Case(f"recordingMeta {column}={value}", set_field(RM, 2, column, value), RM))
    for column, value in (("upperLaneMarkings", "abc"), ("upperLaneMarkings", "nan;1;2"), ("lowerLaneMarkings", "5"),
                          ("lowerLaneMarkings", "24.00;inf"), ("upperLaneMarkings", "30.00;31.00;32.00"),
                          ("lowerLaneMarkings", ";;")):
        cases.append(Case(f"markings {column}={value}", set_field(RM, 2, column, value), RM))
    cases.append(Case("class changed (counts differ)", set_field(TM, 2, "class", "Truck"), None))
    cases.append(Case("direction changed", set_field(TM, 2, "drivingDirection", "1"), None))
    for column, value in (("numFrames", "49"), ("initialFrame", "2"), ("finalFrame", "60"), ("drivingDirection", "3")):
        cases.append(Case(f"tracksMeta {column}={value}", set_field(TM, 2, column, value), TM))
    cases.append(Case("two data rows in recordingMeta", edit_lines(RM, lambda ls: [*ls, ls[1]]), RM))
    return cases


CATALOGUE = catalogue()


@pytest.fixture(scope="module")
def original(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Files]:
    directory = tmp_path_factory.mktemp("highd_original")
    write_recording(sample_recording(1), directory)
    return directory, {name: (directory / name).read_bytes() for name in COLUMNS}


def _read(tmp_path: Path, files: Files) -> object:
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    return read_recording(tmp_path, 1)


def test_catalogue_size() -> None:
    assert len(CATALOGUE) >= 200
    assert len({c.name for c in CATALOGUE}) == len(CATALOGUE)


@pytest.mark.parametrize("case", CATALOGUE, ids=[c.name for c in CATALOGUE])
def test_corrupted_recording_is_a_clear_error(case: Case, original: tuple[Path, Files], tmp_path: Path) -> None:
    _, files = original
    edited = case.edit(dict(files))
    assert edited != files, "the corruption changed nothing"
    with pytest.raises(HighDFormatError) as info:
        _read(tmp_path, edited)
    err = info.value
    assert err.path.name in COLUMNS and str(err).startswith(f"{err.path.name}: ")
    if case.file is not None:
        assert err.path.name == case.file, str(err)
    if case.located:
        assert err.column is not None or err.line is not None, str(err)
    if case.column is not None:
        assert err.column == case.column, str(err)
    assert "Traceback" not in str(err) and len(str(err)) < 400


# --- random byte-level damage -----------------------------------------------------------------------

_damage = st.sampled_from(["truncate", "flip", "zero", "insert", "delete_line", "duplicate_line"])


@fuzz(300)
@given(st.sampled_from(sorted(COLUMNS)), _damage, st.integers(0, 10**9), st.integers(1, 64), st.binary(min_size=1,
                                                                                                     max_size=8))
def test_random_damage_is_an_error_or_a_valid_recording(
    original: tuple[Path, Files], name: str, kind: str, where: int, width: int, junk: bytes
) -> None:
    directory, files = original
    data = files[name]
    pos = where % len(data)
    if kind == "truncate":
        damaged = data[:pos]
    elif kind == "flip":
        damaged = data[:pos] + bytes([data[pos] ^ junk[0]]) + data[pos + 1 :]
    elif kind == "zero":
        damaged = data[:pos] + b"\x00" * width + data[pos + width :]
    elif kind == "insert":
        damaged = data[:pos] + junk + data[pos:]
    else:
        lines = data.splitlines(keepends=True)
        k = pos % len(lines)
        damaged = b"".join(lines[:k] + (lines[k + 1 :] if kind == "delete_line" else lines[k:]))
    work = directory.parent / f"damaged_{name}_{kind}_{pos}_{width}_{junk.hex()}"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir()
    try:
        try:
            rec = _read(work, {**files, name: damaged})
        except HighDFormatError as err:
            assert err.path.name in COLUMNS and str(err).startswith(f"{err.path.name}: ")
            return
        validate_recording(rec)  # type: ignore[arg-type]  # what the reader returns is valid HighD
        assert np.isfinite(rec.tracks.select_dtypes("number").to_numpy(dtype=np.float64)).all()  # type: ignore[attr-defined]
    finally:
        shutil.rmtree(work, ignore_errors=True)
