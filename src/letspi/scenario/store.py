"""ScenarioBatch ↔ Arrow IPC file (zstd; Parquet with a ``.parquet`` suffix), one row per scenario.

Array fields are flattened fixed-size lists with their shapes in the schema metadata, which also holds the
schema version and a CRC-32 of every column; loading verifies them and reads all-or-nothing, and writes replace
the target only when complete. Every anticipated problem raises ``ScenarioFileError`` (a ``ValueError``) whose
message starts with the path. Files without checksums load unverified.
"""

from __future__ import annotations

import json
import os
import zlib
from dataclasses import fields
from pathlib import Path
from typing import Any, Final

import numpy as np
import pyarrow as pa
import pyarrow.ipc as ipc
import pyarrow.parquet as pq

from letspi.scenario.types import SCHEMA_VERSION, ScenarioBatch

_META_KEY: Final = b"letspi"
_ARROW_MAGIC: Final = b"ARROW1"
_PARQUET_MAGIC: Final = b"PAR1"
_RECREATE: Final = "re-create it with `letspi data scenarios`"
#: Exceptions pyarrow, numpy and json raise on damaged input (ArrowInvalid is a ValueError;
#: a failed zstd decompression is an OSError).
_DAMAGE: Final = (pa.ArrowException, OSError, ValueError, KeyError, TypeError, IndexError, OverflowError, MemoryError)


class ScenarioFileError(ValueError):
    """A scenario file that cannot be read: ``path``, ``reason``; the message is ``"<path>: <reason>"``."""

    def __init__(self, path: Path | str, reason: str) -> None:
        self.path = Path(path)
        self.reason = reason
        super().__init__(f"{path}: {reason}")

    def __reduce__(self) -> tuple[Any, ...]:
        return (ScenarioFileError, (self.path, self.reason))


def _corrupted(path: Path, detail: object) -> ScenarioFileError:
    text = str(detail).strip().splitlines()[0][:200] if str(detail).strip() else type(detail).__name__
    return ScenarioFileError(path, f"truncated or corrupted scenario file ({text}); {_RECREATE}")


def _column_crc(column: pa.Array | pa.ChunkedArray) -> int:
    """CRC-32 of a column's row count, null count and values (lists flattened, strings NUL-joined); the same for
    Arrow and Parquet (which reads fixed-size lists back as plain lists)."""
    arr = column.combine_chunks() if isinstance(column, pa.ChunkedArray) else column
    crc = zlib.crc32(f"{len(arr)}|{arr.null_count}".encode())
    if pa.types.is_fixed_size_list(arr.type) or pa.types.is_list(arr.type) or pa.types.is_large_list(arr.type):
        arr = arr.flatten()
    if pa.types.is_string(arr.type) or pa.types.is_large_string(arr.type):
        return zlib.crc32("\0".join(str(s) for s in arr.to_pylist()).encode("utf-8", "surrogatepass"), crc)
    values = np.ascontiguousarray(arr.to_numpy(zero_copy_only=False)).reshape(-1)
    return zlib.crc32(values.view(np.uint8).data, crc)


def _checksums(table: pa.Table) -> dict[str, int]:
    return {name: _column_crc(table.column(name)) for name in table.column_names}


def save_scenarios(batch: ScenarioBatch, path: Path, extra_meta: dict[str, object] | None = None) -> Path:
    """Write ``batch`` to ``path`` (Arrow IPC; Parquet if the suffix is ``.parquet``). Returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    columns: dict[str, pa.Array] = {}
    shapes: dict[str, list[int]] = {}
    dtypes: dict[str, str] = {}
    for f in fields(ScenarioBatch):
        arr = getattr(batch, f.name)
        if arr.dtype == object:  # text columns (scenario_id, recording_key)
            columns[f.name] = pa.array([str(s) for s in arr], type=pa.string())
            continue
        inner = tuple(arr.shape[1:])
        shapes[f.name] = list(inner)
        dtypes[f.name] = arr.dtype.str
        if not inner:
            columns[f.name] = pa.array(arr)
            continue
        size = int(np.prod(inner))
        if size == 0:  # e.g. no context vehicles anywhere: Arrow lists need a positive size
            columns[f.name] = pa.nulls(len(arr), type=pa.int8())
            continue
        flat = np.ascontiguousarray(arr).reshape(-1)
        if arr.dtype == bool:
            values = pa.array(flat.astype(np.uint8))
        else:
            values = pa.array(flat)
        columns[f.name] = pa.FixedSizeListArray.from_arrays(values, size)
    table = pa.table(columns)
    meta = {
        "schema_version": SCHEMA_VERSION,
        "shapes": shapes,
        "dtypes": dtypes,
        "frame": "ego frame: origin ego centre at t=0, x along travel, y left; SI units",
        **(extra_meta or {}),
        "num_rows": table.num_rows,
        "checksums": {"algorithm": "crc32", "columns": _checksums(table)},
    }
    table = table.replace_schema_metadata({_META_KEY: json.dumps(meta).encode()})
    tmp = path.with_name(path.name + ".tmp")
    try:
        if path.suffix == ".parquet":
            pq.write_table(table, tmp, compression="zstd")
        else:
            with ipc.new_file(tmp, table.schema, options=ipc.IpcWriteOptions(compression="zstd")) as writer:
                writer.write_table(table)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())  # complete on disk before it replaces the target
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def _format_of(path: Path) -> str:
    """``"parquet"`` or ``"arrow"`` from the file's signatures; raises ``ScenarioFileError`` otherwise."""
    try:
        size = path.stat().st_size
        with open(path, "rb") as fh:
            head = fh.read(8)
            fh.seek(max(size - 8, 0))
            tail = fh.read(8)
    except FileNotFoundError:
        raise ScenarioFileError(path, "no such scenario file") from None
    except IsADirectoryError:
        raise ScenarioFileError(path, "is a directory, not a scenario file") from None
    except OSError as exc:
        raise ScenarioFileError(path, f"cannot read the scenario file ({exc.strerror or exc})") from None
    if size == 0:
        raise ScenarioFileError(path, f"empty file (0 bytes): truncated or corrupted scenario file; {_RECREATE}")
    if head.startswith(_PARQUET_MAGIC) or tail.endswith(_PARQUET_MAGIC):
        return "parquet"
    if head.startswith(_ARROW_MAGIC) or tail.endswith(_ARROW_MAGIC):
        return "arrow"
    raise ScenarioFileError(
        path,
        "not a letspi scenario file (Arrow or Parquet): no Arrow or Parquet signature at either end "
        f"(if it was one, it is truncated or corrupted; {_RECREATE})",
    )


def _read_schema(path: Path, kind: str) -> pa.Schema:
    try:
        if kind == "parquet":
            return pq.read_schema(path)
        with pa.memory_map(str(path)) as source:
            return ipc.open_file(source).schema
    except _DAMAGE as exc:
        raise _corrupted(path, exc) from None


def _check_meta(path: Path, meta: object) -> dict[str, Any]:
    """Schema version first (an old file gets the version message), then the structure."""
    if not isinstance(meta, dict):
        raise _corrupted(path, "letspi metadata is not a JSON object")
    version = meta.get("schema_version")
    if version is None:
        raise _corrupted(path, "letspi metadata without a schema version")
    if version != SCHEMA_VERSION:
        raise ScenarioFileError(
            path,
            f"scenario schema version {version} found, this letspi reads version {SCHEMA_VERSION}; {_RECREATE}",
        )
    for key in ("shapes", "dtypes"):
        if not isinstance(meta.get(key), dict):
            raise _corrupted(path, f"letspi metadata without '{key}'")
    return meta


def read_scenario_meta(path: Path) -> dict[str, object]:
    """The letspi metadata dict of a scenario file (schema version, shapes, provenance)."""
    path = Path(path)
    schema = _read_schema(path, _format_of(path))
    raw = (schema.metadata or {}).get(_META_KEY)
    if raw is None:
        raise ScenarioFileError(path, "file without letspi metadata (not written by letspi?)")
    try:
        meta = json.loads(raw)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError, bad UTF-8
        raise _corrupted(path, f"letspi metadata is not valid JSON: {exc}") from None
    return _check_meta(path, meta)


def _read_table(path: Path, kind: str) -> pa.Table:
    if kind == "parquet":
        return pq.read_table(path)
    with pa.memory_map(str(path)) as source:
        return ipc.open_file(source).read_all()


def _verify(path: Path, table: pa.Table, meta: dict[str, Any]) -> None:
    table.validate(full=True)  # offsets, lengths, list sizes: before anything reads the buffers
    expected_rows = meta.get("num_rows")
    if expected_rows is not None and table.num_rows != expected_rows:
        raise _corrupted(path, f"{table.num_rows} rows, the metadata says {expected_rows}")
    sums = meta.get("checksums")
    if sums is None:
        return  # written before checksums existed
    if not isinstance(sums, dict) or sums.get("algorithm") != "crc32" or not isinstance(sums.get("columns"), dict):
        raise _corrupted(path, "unreadable checksum record in the metadata")
    expected: dict[str, Any] = sums["columns"]
    for name in table.column_names:
        if name in expected and _column_crc(table.column(name)) != expected[name]:
            raise _corrupted(path, f"checksum mismatch in column '{name}'")


def _to_batch(path: Path, table: pa.Table, meta: dict[str, Any]) -> ScenarioBatch:
    shapes: dict[str, list[int]] = meta["shapes"]
    dtypes: dict[str, str] = meta["dtypes"]
    out: dict[str, np.ndarray] = {}
    for f in fields(ScenarioBatch):
        if f.name not in table.column_names:
            raise ScenarioFileError(path, f"missing column '{f.name}' (not a letspi scenario file, or {_RECREATE})")
        col = table.column(f.name).combine_chunks()
        if pa.types.is_string(col.type):
            out[f.name] = np.asarray(col.to_pylist(), dtype=object)
            continue
        inner = tuple(int(n) for n in shapes[f.name])
        dtype = np.dtype(dtypes[f.name])
        if not inner:
            out[f.name] = col.to_numpy(zero_copy_only=False).astype(dtype, copy=False)
            continue
        if 0 in inner:
            out[f.name] = np.zeros((table.num_rows, *inner), dtype=dtype)
            continue
        values = col.flatten().to_numpy(zero_copy_only=False)
        arr = values.astype(dtype, copy=False)
        out[f.name] = arr.reshape((table.num_rows, *inner))
    return ScenarioBatch(**out)


def load_scenarios(path: Path, indices: np.ndarray | list[int] | None = None) -> ScenarioBatch:
    """Read a scenario file (optionally only the rows ``indices``), verified (module docstring)."""
    path = Path(path)
    meta = read_scenario_meta(path)
    kind = _format_of(path)
    try:
        table = _read_table(path, kind)
        _verify(path, table, meta)
    except ScenarioFileError:
        raise
    except _DAMAGE as exc:
        raise _corrupted(path, exc) from None
    if indices is not None:
        idx = np.asarray(indices, dtype=np.int64)
        if len(idx) and (idx.min() < 0 or idx.max() >= table.num_rows):
            raise ScenarioFileError(path, f"index out of range 0..{table.num_rows - 1}")
        table = table.take(pa.array(idx))
    try:
        return _to_batch(path, table, meta)
    except ScenarioFileError:
        raise
    except _DAMAGE as exc:  # shapes/dtypes that do not fit the data
        raise _corrupted(path, exc) from None


def count_scenarios(path: Path) -> int:
    """Number of scenarios in the file (from the metadata; older files: from the row batches)."""
    path = Path(path)
    meta = read_scenario_meta(path)
    rows = meta.get("num_rows")
    if isinstance(rows, int) and not isinstance(rows, bool) and rows >= 0:
        return rows
    try:
        if _format_of(path) == "parquet":
            return int(pq.ParquetFile(path).metadata.num_rows)
        with pa.memory_map(str(path)) as source:
            reader = ipc.open_file(source)
            return sum(reader.get_batch(i).num_rows for i in range(reader.num_record_batches))
    except _DAMAGE as exc:
        raise _corrupted(path, exc) from None
