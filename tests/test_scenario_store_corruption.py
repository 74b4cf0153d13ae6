"""Damaged scenario files (issue 15): a ``ScenarioFileError`` naming the file and saying "truncated or
corrupted" (or the schema version found and expected), never a pyarrow/zstd traceback, never part
of a batch, never silently different numbers."""

from __future__ import annotations

import json
import shutil
from dataclasses import fields
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.ipc as ipc
import pytest
from fuzz_settings import fuzz
from hypothesis import assume, given
from hypothesis import strategies as st
from scenario_support import noisy_batch

import letspi.scenario.store as store
from letspi.scenario.store import ScenarioFileError, count_scenarios, load_scenarios, read_scenario_meta, save_scenarios
from letspi.scenario.types import SCHEMA_VERSION, ScenarioBatch

DAMAGED = "truncated or corrupted"


def same(a: ScenarioBatch, b: ScenarioBatch) -> bool:
    return all(
        np.array_equal(getattr(a, f.name), getattr(b, f.name), equal_nan=getattr(a, f.name).dtype.kind == "f")
        for f in fields(ScenarioBatch)
    )


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, ScenarioBatch]]:
    directory = tmp_path_factory.mktemp("scenario_files")
    small = noisy_batch(12)
    big = noisy_batch(520, seed=1)
    return {
        "arrow": (save_scenarios(small, directory / "small.arrow"), small),
        "parquet": (save_scenarios(small, directory / "small.parquet"), small),
        "big": (save_scenarios(big, directory / "big.arrow"), big),
    }


def _expect_damaged(path: Path) -> ScenarioFileError:
    with pytest.raises(ScenarioFileError) as info:
        load_scenarios(path)
    err = info.value
    assert str(err).startswith(f"{path}: ") and err.path == path
    assert DAMAGED in str(err) and "letspi data scenarios" in str(err)
    assert "\n" not in str(err) and len(str(err)) < 400
    return err


def test_one_megabyte_zeroed_in_the_middle(files: dict[str, tuple[Path, ScenarioBatch]], tmp_path: Path) -> None:
    src, _ = files["big"]
    data = src.read_bytes()
    assert len(data) > 2_000_000  # header and footer stay intact
    mid = len(data) // 2
    damaged = tmp_path / "zeroed.arrow"
    damaged.write_bytes(data[: mid - 500_000] + b"\x00" * 1_000_000 + data[mid + 500_000 :])
    err = _expect_damaged(damaged)
    assert "ZSTD" in str(err) or "checksum" in str(err)
    with pytest.raises(ScenarioFileError, match=DAMAGED):
        load_scenarios(damaged, [0])  # a subset too: nothing partial


@pytest.mark.parametrize("kind", ["arrow", "parquet"])
@pytest.mark.parametrize("keep", [0.0, 0.1, 0.5, 0.9, 0.999])
def test_truncated(files: dict[str, tuple[Path, ScenarioBatch]], tmp_path: Path, kind: str, keep: float) -> None:
    src, _ = files[kind]
    data = src.read_bytes()
    damaged = tmp_path / src.name
    damaged.write_bytes(data[: int(len(data) * keep)])
    _expect_damaged(damaged)
    with pytest.raises(ScenarioFileError, match=DAMAGED):
        count_scenarios(damaged)


@pytest.mark.parametrize("kind", ["arrow", "parquet"])
def test_flipped_data_byte_is_caught_by_the_checksum(
    files: dict[str, tuple[Path, ScenarioBatch]], tmp_path: Path, kind: str
) -> None:
    src, batch = files[kind]
    data = bytearray(src.read_bytes())
    caught = 0
    for pos in range(len(data) // 5, 4 * len(data) // 5, max(len(data) // 60, 1)):
        damaged = tmp_path / f"{pos}_{src.name}"
        flipped = bytearray(data)
        flipped[pos] ^= 0x40
        damaged.write_bytes(bytes(flipped))
        try:
            back = load_scenarios(damaged)
        except ScenarioFileError as err:
            assert DAMAGED in str(err)
            caught += 1
            continue
        assert same(back, batch), f"byte {pos} changed the data silently"
    assert caught > 0


def test_old_schema_version(files: dict[str, tuple[Path, ScenarioBatch]], tmp_path: Path,
                            monkeypatch: pytest.MonkeyPatch) -> None:
    _, batch = files["arrow"]
    monkeypatch.setattr(store, "SCHEMA_VERSION", SCHEMA_VERSION - 1)
    old = save_scenarios(batch, tmp_path / "old.arrow")
    monkeypatch.setattr(store, "SCHEMA_VERSION", SCHEMA_VERSION)
    for fn in (load_scenarios, count_scenarios, read_scenario_meta):
        with pytest.raises(ScenarioFileError) as info:
            fn(old)
        assert str(info.value) == (
            f"{old}: scenario schema version {SCHEMA_VERSION - 1} found, this letspi reads version "
            f"{SCHEMA_VERSION}; re-create it with `letspi data scenarios`"
        )


@pytest.mark.parametrize(
    "raw",
    [b"{not json", b"[1, 2]", b'{"shapes": {}, "dtypes": {}}', b'{"schema_version": SV, "dtypes": {}}', b"\xff\xfe"],
)
def test_damaged_metadata(tmp_path: Path, raw: bytes) -> None:
    raw = raw.replace(b"SV", str(SCHEMA_VERSION).encode())
    path = tmp_path / "meta.arrow"
    table = pa.table({"scenario_id": ["a"]}).replace_schema_metadata({b"letspi": raw})
    with ipc.new_file(path, table.schema) as writer:
        writer.write_table(table)
    with pytest.raises(ScenarioFileError, match=DAMAGED):
        load_scenarios(path)


def test_other_files(tmp_path: Path) -> None:
    empty = tmp_path / "empty.arrow"
    empty.write_bytes(b"")
    assert DAMAGED in str(_expect_damaged(empty))
    text = tmp_path / "notes.arrow"
    text.write_text("hello, I am not a scenario file")
    with pytest.raises(ScenarioFileError, match="notes.arrow: not a letspi scenario file"):
        load_scenarios(text)
    with pytest.raises(ScenarioFileError, match="is a directory"):
        load_scenarios(tmp_path)
    with pytest.raises(ScenarioFileError, match="no such scenario file"):
        count_scenarios(tmp_path / "missing.arrow")


def test_checksums_and_row_count_are_recorded(files: dict[str, tuple[Path, ScenarioBatch]]) -> None:
    path, batch = files["arrow"]
    meta = read_scenario_meta(path)
    assert meta["num_rows"] == len(batch) == count_scenarios(path)
    sums = meta["checksums"]
    assert isinstance(sums, dict) and sums["algorithm"] == "crc32"
    assert set(sums["columns"]) == {f.name for f in fields(ScenarioBatch)}
    json.dumps(meta)  # plain JSON


def test_file_without_checksums_still_loads(files: dict[str, tuple[Path, ScenarioBatch]], tmp_path: Path) -> None:
    # files written before checksums existed (same schema version) load unverified
    path, batch = files["arrow"]
    with pa.memory_map(str(path)) as source:
        table = ipc.open_file(source).read_all()
    meta = json.loads(table.schema.metadata[b"letspi"])
    del meta["checksums"], meta["num_rows"]
    older = tmp_path / "older.arrow"
    with ipc.new_file(older, table.schema.with_metadata({b"letspi": json.dumps(meta).encode()})) as writer:
        writer.write_table(table.replace_schema_metadata({b"letspi": json.dumps(meta).encode()}))
    assert same(load_scenarios(older), batch) and count_scenarios(older) == len(batch)


def test_failed_write_leaves_no_temporary_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def boom(*args: object, **kwargs: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(store.os, "fsync", boom)
    with pytest.raises(OSError, match="No space left"):
        save_scenarios(noisy_batch(2), tmp_path / "s.arrow")
    assert list(tmp_path.iterdir()) == []


# --- fuzz: truncations at random offsets, zeroed ranges, flipped bytes ------------------------------


@fuzz(300)
@given(
    kind=st.sampled_from(["arrow", "parquet"]),
    damage=st.sampled_from(["truncate", "zero", "flip"]),
    where=st.floats(0.0, 1.0),
    width=st.integers(1, 4096),
    mask=st.integers(1, 255),
)
def test_fuzz_damage(
    files: dict[str, tuple[Path, ScenarioBatch]], kind: str, damage: str, where: float, width: int, mask: int
) -> None:
    src, batch = files[kind]
    data = src.read_bytes()
    pos = min(int(where * len(data)), len(data) - 1)
    if damage == "truncate":
        damaged_bytes = data[:pos]
    elif damage == "zero":
        damaged_bytes = data[:pos] + b"\x00" * min(width, len(data) - pos) + data[pos + width :]
    else:
        damaged_bytes = data[:pos] + bytes([data[pos] ^ mask]) + data[pos + 1 :]
    assume(damaged_bytes != data)  # zeroing bytes that are already zero damages nothing
    work = src.parent / f"fuzz_{kind}_{damage}_{pos}_{width}_{mask}"
    work.mkdir(exist_ok=True)
    damaged = work / src.name
    damaged.write_bytes(damaged_bytes)
    try:
        try:
            back = load_scenarios(damaged)
        except ScenarioFileError as err:
            assert str(err).startswith(f"{damaged}: ")
            assert DAMAGED in str(err) or "schema version" in str(err) or "not a letspi scenario file" in str(err)
            return
        assert same(back, batch), "damage changed the data silently"
        try:
            assert count_scenarios(damaged) == len(batch)
        except ScenarioFileError as err:  # pragma: no cover - metadata damage is caught by load first
            raise AssertionError(f"load succeeded but count failed: {err}") from None
    finally:
        shutil.rmtree(work, ignore_errors=True)
