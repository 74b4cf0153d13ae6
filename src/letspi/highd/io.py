"""Read and write HighD recordings (``NN_tracks.csv``, ``NN_tracksMeta.csv``, ``NN_recordingMeta.csv``).

Reading parses with explicit dtypes and validates vectorised; only on a failure is the file scanned again to
name the column and the 1-based CSV line (header = line 1) in a ``HighDFormatError``.
"""

from __future__ import annotations

import os
import re
import tempfile
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pa_csv
from PIL import Image

from letspi.fsutil import atomic_write
from letspi.highd.errors import HighDFormatError
from letspi.highd.schema import (
    HIGHWAY_IMAGE_M_PER_PX,
    RECORDING_META_COLUMNS,
    RECORDING_META_INT_COLUMNS,
    RECORDING_META_STR_COLUMNS,
    TRACKS_COLUMNS,
    TRACKS_INT_COLUMNS,
    TRACKS_META_COLUMNS,
    TRACKS_META_INT_COLUMNS,
    TRACKS_META_STR_COLUMNS,
    highway_image_file,
    recording_meta_file,
    tracks_file,
    tracks_meta_file,
)
from letspi.highd.types import Recording
from letspi.highd.validate import (
    LineOf,
    markings_of,
    validate_counts,
    validate_recording_meta,
    validate_tracks,
    validate_tracks_meta,
)

__all__ = [
    "FLOAT_DECIMALS",
    "list_recording_ids",
    "read_recording",
    "read_recording_meta",
    "read_recordings",
    "validate_recording",
    "write_highway_image",
    "write_recording",
]

#: Floats are written as real HighD prints them, fixed-point with 2 decimals (``51.20``, ``-1.00``), so readers that
#: infer column types (``lxd-io``, polars) see floats; a write→read round trip is exact to 0.005.
FLOAT_DECIMALS = 2

_FILE_RE = re.compile(r"^(\d+)_(?:tracks|tracksMeta|recordingMeta)\.csv$")


@dataclass(frozen=True)
class _TableSpec:
    columns: tuple[str, ...]
    int_columns: frozenset[str]
    str_columns: frozenset[str]

    @property
    def float_columns(self) -> list[str]:
        return [c for c in self.columns if c not in self.int_columns and c not in self.str_columns]

    def dtypes(self) -> dict[str, str]:
        return {
            c: "int64" if c in self.int_columns else "str" if c in self.str_columns else "float64" for c in self.columns
        }


_TRACKS = _TableSpec(TRACKS_COLUMNS, TRACKS_INT_COLUMNS, frozenset())
_TRACKS_META = _TableSpec(TRACKS_META_COLUMNS, TRACKS_META_INT_COLUMNS, TRACKS_META_STR_COLUMNS)
_RECORDING_META = _TableSpec(RECORDING_META_COLUMNS, RECORDING_META_INT_COLUMNS, RECORDING_META_STR_COLUMNS)


def _in_memory_line(row: int) -> int:
    return row + 2


def list_recording_ids(directory: Path) -> list[int]:
    """Recording ids ``NN`` in ``directory``, ascending; any one of a recording's three files counts."""
    directory = Path(directory)
    if not directory.is_dir():
        raise FileNotFoundError(f"not a directory: {directory}")
    ids = {int(m.group(1)) for p in directory.iterdir() if (m := _FILE_RE.match(p.name)) and p.is_file()}
    return sorted(ids)


def _read_header(path: Path) -> list[str]:
    if not path.is_file():
        raise HighDFormatError(path, "file not found")
    try:
        with path.open("r", newline="", encoding="utf-8-sig") as fh:
            first = fh.readline()
    except UnicodeDecodeError as exc:
        raise HighDFormatError(path, "not UTF-8 text", line=1) from exc
    except OSError as exc:  # permissions, I/O errors
        raise HighDFormatError(path, f"cannot read the file ({exc.strerror or exc})") from exc
    header = first.rstrip("\r\n")
    if not header.strip():
        raise HighDFormatError(path, "empty file (no header)")
    return header.split(",")


def _data_lines(path: Path, n_fields: int) -> list[int]:
    """Line numbers of the data rows pandas keeps (blank lines skipped); raises at a wrong field count."""
    lines: list[int] = []
    with path.open("r", newline="", encoding="utf-8-sig") as fh:
        next(fh, None)
        for lineno, raw in enumerate(fh, start=2):
            text = raw.rstrip("\r\n")
            if not text:
                continue
            found = text.count(",") + 1
            if found != n_fields:
                raise HighDFormatError(
                    path, f"expected {n_fields} fields, found {found} (truncated or malformed line)", line=lineno
                )
            lines.append(lineno)
    return lines


def _bad_rows(frame: pd.DataFrame, col: str, spec: _TableSpec) -> np.ndarray:
    """Boolean mask (N,) of rows of ``col`` that do not parse, from a dtype-inferred read."""
    series = frame[col]
    if col in spec.str_columns:
        return series.isna().to_numpy()
    values = pd.to_numeric(series, errors="coerce").to_numpy(dtype=np.float64)
    bad = ~np.isfinite(values)
    if col in spec.int_columns:
        # pandas' int64 parser accepts integral text such as "7.0" or "1e3"; reject the rest
        finite = np.where(bad, 0.0, values)
        bad |= (finite != np.round(finite)) | (np.abs(finite) >= 2.0**63)
    return bad


def _raw_field(path: Path, line: int, index: int) -> str:
    with path.open("r", newline="", encoding="utf-8-sig") as fh:
        for lineno, raw in enumerate(fh, start=1):
            if lineno == line:
                return raw.rstrip("\r\n").split(",")[index]
    raise AssertionError("line not found")  # pragma: no cover - callers pass existing lines


def _describe(value: str, kind: str) -> str:
    """Reason text for a raw field that failed to parse as ``kind`` ("int", "float" or "str")."""
    if not value.strip():
        return "empty value"
    if kind == "str":
        return f"missing value ({value!r})"  # pandas reads "NA", "null", ... as missing
    try:
        number = float(value)
    except ValueError:
        return f"not a number ({value!r})"
    if not np.isfinite(number):
        return f"not a finite number ({value!r})"
    if kind == "int":
        return f"not an integer ({value!r})"
    return f"invalid value ({value!r})"  # pragma: no cover - a finite float always parses


def _locate_parse_error(path: Path, header: list[str], spec: _TableSpec, cause: Exception | None) -> None:
    """Slow path: raise the line and column that made the fast parse fail (field counts, then a typed parse)."""
    if isinstance(cause, UnicodeDecodeError):
        raise HighDFormatError(path, f"not UTF-8 text ({cause.reason} at byte {cause.start})") from cause
    data_lines = _data_lines(path, len(header))  # raises on a wrong field count
    try:
        frame = pd.read_csv(path, index_col=False, engine="c", low_memory=False)
    except (ValueError, OverflowError):  # e.g. an integer beyond uint64: compare as text instead
        frame = pd.read_csv(path, index_col=False, engine="c", low_memory=False, dtype=str, keep_default_na=True)
    best: tuple[int, str] | None = None
    for col in spec.columns:
        bad = _bad_rows(frame, col, spec)
        if bad.any() and (best is None or int(np.argmax(bad)) < best[0]):
            best = (int(np.argmax(bad)), col)
    if best is None:
        raise HighDFormatError(path, f"could not be parsed ({cause})") from cause
    row, col = best
    line = data_lines[row]
    kind = "int" if col in spec.int_columns else "str" if col in spec.str_columns else "float"
    reason = _describe(_raw_field(path, line, header.index(col)), kind)
    raise HighDFormatError(path, reason, column=col, line=line)


def _read_table(path: Path, spec: _TableSpec) -> tuple[pd.DataFrame, LineOf]:
    """One HighD CSV with exactly ``spec.columns`` in official order, and a lazy map data row -> CSV line."""
    header = _read_header(path)
    for col in spec.columns:
        if col not in header:
            raise HighDFormatError(path, "missing column", column=col)
    duplicated = sorted({h for h in header if header.count(h) > 1})
    if duplicated:
        raise HighDFormatError(path, "duplicated column in header", column=duplicated[0])
    try:
        with warnings.catch_warnings():
            # pandas only *warns* when the first data row has more fields than the header
            warnings.simplefilter("error", pd.errors.ParserWarning)
            # an out-of-range integer warns before raising; the slow path reports it properly
            warnings.simplefilter("ignore", RuntimeWarning)
            # no usecols: it would hide rows with surplus fields from the parser's checks
            frame = pd.read_csv(path, dtype=spec.dtypes(), index_col=False, engine="c")
    except (ValueError, OverflowError, pd.errors.ParserWarning) as exc:  # ParserError subclasses ValueError
        _locate_parse_error(path, header, spec, exc)
        raise  # unreachable: the slow path always raises
    frame = frame[list(spec.columns)]
    if len(frame) == 0:
        raise HighDFormatError(path, "no data rows (header only)")
    floats = spec.float_columns
    ok = bool(np.isfinite(frame[floats].to_numpy(dtype=np.float64)).all()) if floats else True
    strs = [c for c in spec.columns if c in spec.str_columns]
    if strs:
        ok = ok and not bool(frame[strs].isna().to_numpy().any())
    if not ok:  # NaN from an empty or missing field, or a literal nan/inf
        _locate_parse_error(path, header, spec, None)

    cache: list[list[int]] = []

    def line_of(row: int) -> int:
        if not cache:
            cache.append(_data_lines(path, len(header)))
        return cache[0][row]

    return frame, line_of


def _sort_tracks(tracks: pd.DataFrame) -> tuple[pd.DataFrame, np.ndarray | None]:
    """Sort by (id, frame), stably. Returns the frame and the original positions (None if already sorted)."""
    ids = tracks["id"].to_numpy()
    frames = tracks["frame"].to_numpy()
    d_id = np.diff(ids)
    if bool(np.all((d_id > 0) | ((d_id == 0) & (np.diff(frames) >= 0)))):
        return tracks, None
    order = np.lexsort((frames, ids))
    return tracks.iloc[order].reset_index(drop=True), order


def _composed(line_of: LineOf, order: np.ndarray | None) -> LineOf:
    if order is None:
        return line_of
    return lambda k: line_of(int(order[k]))


def _scalar(value: object, col: str) -> object:
    if col in RECORDING_META_INT_COLUMNS:
        return int(value)  # type: ignore[call-overload]
    if col in RECORDING_META_STR_COLUMNS:
        return str(value)
    return float(value)  # type: ignore[arg-type]


def read_recording(directory: Path, recording_id: int) -> Recording:
    """Read and validate recording ``recording_id`` of ``directory``, tracks sorted by (id, frame); columns are int64,
    float64 or str. Raises ``HighDFormatError`` (module doc)."""
    directory = Path(directory)
    rm_path = directory / recording_meta_file(recording_id)
    tm_path = directory / tracks_meta_file(recording_id)
    tr_path = directory / tracks_file(recording_id)

    rm, rm_line, tm, tm_line = _read_metas(directory, recording_id)
    markings = markings_of(rm_path, rm, rm_line)
    tracks, tr_line = _read_table(tr_path, _TRACKS)
    tracks, order = _sort_tracks(tracks)
    validate_tracks(tracks, tm, markings, tr_path, tm_path, _composed(tr_line, order), tm_line)
    validate_counts(rm, tm, rm_path, rm_line, tm_path)

    meta = {col: _scalar(rm[col].iloc[0], col) for col in RECORDING_META_COLUMNS}
    return Recording(recording_id=recording_id, meta=meta, tracks_meta=tm, tracks=tracks)


def _read_metas(directory: Path, recording_id: int) -> tuple[pd.DataFrame, LineOf, pd.DataFrame, LineOf]:
    """The validated recording meta and tracks meta tables of a recording, with their line maps."""
    rm_path = directory / recording_meta_file(recording_id)
    tm_path = directory / tracks_meta_file(recording_id)
    rm, rm_line = _read_table(rm_path, _RECORDING_META)
    validate_recording_meta(rm, recording_id, rm_path, rm_line)
    tm, tm_line = _read_table(tm_path, _TRACKS_META)
    validate_tracks_meta(tm, tm_path, tm_line)
    return rm, rm_line, tm, tm_line


def read_recording_meta(directory: Path, recording_id: int) -> tuple[dict[str, object], pd.DataFrame]:
    """``(meta, tracks_meta)`` of a recording without its tracks (validated as in ``read_recording``, except the
    checks that need the tracks): what ``letspi.scenario.extract.recording_key_of`` is computed from."""
    rm, _, tm, _ = _read_metas(Path(directory), recording_id)
    return {col: _scalar(rm[col].iloc[0], col) for col in RECORDING_META_COLUMNS}, tm


def read_recordings(directory: Path, ids: Sequence[int] | None = None) -> list[Recording]:
    """Read all recordings in ``directory`` (``ids=None``) or the chosen ``ids``, in the given order."""
    chosen = list_recording_ids(directory) if ids is None else list(ids)
    return [read_recording(directory, rid) for rid in chosen]


def _coerce_table(frame: pd.DataFrame, spec: _TableSpec, path: Path) -> pd.DataFrame:
    """Official columns in official order with official dtypes; raises on missing/invalid values."""
    for col in spec.columns:
        if col not in frame.columns:
            raise HighDFormatError(path, "missing column", column=col)
    out: dict[str, object] = {}
    for col in spec.columns:
        series = frame[col].reset_index(drop=True)
        if col in spec.str_columns:
            bad = series.isna().to_numpy()
            if bad.any():
                k = int(np.argmax(bad))
                raise HighDFormatError(path, "empty value", column=col, line=_in_memory_line(k))
            text = series.astype(str)
            # the files are unquoted CSV: these characters cannot be represented
            bad = (text.str.contains(r'[,"\r\n]', regex=True) | (text.str.strip() == "")).to_numpy(dtype=bool)
            if bad.any():
                k = int(np.argmax(bad))
                raise HighDFormatError(
                    path,
                    f"invalid text {text.iloc[k]!r} (empty, or contains ',', '\"' or a newline)",
                    column=col,
                    line=_in_memory_line(k),
                )
            out[col] = text
            continue
        values = pd.to_numeric(series, errors="coerce").to_numpy(dtype=np.float64)
        bad = ~np.isfinite(values)
        if col in spec.int_columns:
            bad |= np.where(bad, False, values != np.round(values))
        if bad.any():
            k = int(np.argmax(bad))
            kind = "an integer" if col in spec.int_columns else "a finite number"
            raise HighDFormatError(path, f"not {kind} ({series.iloc[k]!r})", column=col, line=_in_memory_line(k))
        out[col] = values.astype(np.int64) if col in spec.int_columns else values
    return pd.DataFrame(out)


def _prepare(rec: Recording, directory: Path) -> tuple[list[Path], list[pd.DataFrame]]:
    rid = rec.recording_id
    rm_path = directory / recording_meta_file(rid)
    tm_path = directory / tracks_meta_file(rid)
    tr_path = directory / tracks_file(rid)
    missing = [c for c in RECORDING_META_COLUMNS if c not in rec.meta]
    if missing:
        raise HighDFormatError(rm_path, "missing column", column=missing[0])
    rm = _coerce_table(pd.DataFrame([{c: rec.meta[c] for c in RECORDING_META_COLUMNS}]), _RECORDING_META, rm_path)
    validate_recording_meta(rm, rid, rm_path, _in_memory_line)
    markings = markings_of(rm_path, rm, _in_memory_line)
    tm = _coerce_table(rec.tracks_meta, _TRACKS_META, tm_path)
    validate_tracks_meta(tm, tm_path, _in_memory_line)
    tracks = _coerce_table(rec.tracks, _TRACKS, tr_path)
    tracks, _ = _sort_tracks(tracks)
    # line numbers refer to the sorted rows, i.e. to the file as it would be written
    validate_tracks(tracks, tm, markings, tr_path, tm_path, _in_memory_line, _in_memory_line)
    validate_counts(rm, tm, rm_path, _in_memory_line, tm_path)
    return [rm_path, tm_path, tr_path], [rm, tm, tracks]


def validate_recording(rec: Recording) -> None:
    """Validate an in-memory recording as reading would; the ``HighDFormatError`` names the bare file name the data
    would go to and the line the row would occupy (tracks sorted by (id, frame))."""
    _prepare(rec, Path())


def _fixed_point(values: np.ndarray) -> pa.Array:
    """``values`` (N,) float64 as text with ``FLOAT_DECIMALS`` decimals (never ``-0.00``), via integer hundredths."""
    scale = 10**FLOAT_DECIMALS
    units = np.round(values * scale).astype(np.int64)
    magnitude = np.abs(units)
    whole = pc.cast(pa.array(magnitude // scale), pa.string())
    frac = pc.utf8_lpad(pc.cast(pa.array(magnitude % scale), pa.string()), width=FLOAT_DECIMALS, padding="0")
    sign = pa.array(np.where(units < 0, "-", ""))
    return pc.binary_join_element_wise(sign, whole, ".", frac, "")


def _write_csv(frame: pd.DataFrame, fh: IO[bytes]) -> None:
    """Write a coerced frame as a HighD CSV with pyarrow: floats pre-formatted, strings never quoted."""
    columns = {c: _fixed_point(frame[c].to_numpy()) if frame[c].dtype == np.float64
               else pa.array(frame[c].to_numpy()) for c in frame.columns}
    fh.write((",".join(frame.columns) + "\n").encode("utf-8"))
    table = pa.table(columns)
    pa_csv.write_csv(table, fh, pa_csv.WriteOptions(include_header=False, quoting_style="none"))


def _default_file_mode() -> int:
    umask = os.umask(0o022)  # the only portable way to read the umask is to set it
    os.umask(umask)
    return 0o666 & ~umask


def write_recording(rec: Recording, directory: Path) -> list[Path]:
    """Validate ``rec`` and write its three CSVs into ``directory`` (created if needed). All three go to hidden
    temporary files first and are renamed only once all were written; on failure nothing existing changes. Returns
    ``[NN_recordingMeta.csv, NN_tracksMeta.csv, NN_tracks.csv]``. Raises ``HighDFormatError`` (nothing written) when
    ``rec`` is not valid HighD."""
    directory = Path(directory)
    paths, frames = _prepare(rec, directory)
    directory.mkdir(parents=True, exist_ok=True)
    mode = _default_file_mode()
    temps: list[Path] = []
    try:
        for path, frame in zip(paths, frames, strict=True):
            fd, tmp_name = tempfile.mkstemp(dir=directory, prefix=f".{path.name}.", suffix=".tmp")
            temps.append(Path(tmp_name))
            os.chmod(fd, mode)  # mkstemp creates 0600; give the files the usual umask-based mode
            with os.fdopen(fd, "wb") as fh:
                _write_csv(frame, fh)
        for tmp_path, path in zip(temps, paths, strict=True):
            os.replace(tmp_path, path)
    except BaseException:
        for tmp_path in temps:
            tmp_path.unlink(missing_ok=True)
        raise
    return paths


def write_highway_image(directory: Path, recording_id: int, upper_markings_y_m: Sequence[float],
                        lower_markings_y_m: Sequence[float], length_m: float) -> Path:
    """Draw the road of a recording as its ``NN_highway.png`` (real HighD's aerial view; ``lxd-io`` needs it) at
    ``HIGHWAY_IMAGE_M_PER_PX``, in the tracks' image axes: grey carriageways, white markings."""
    upper, lower = np.sort(np.asarray(upper_markings_y_m)), np.sort(np.asarray(lower_markings_y_m))
    height_px = int(np.ceil((lower[-1] + upper[0]) / HIGHWAY_IMAGE_M_PER_PX))
    width_px = int(np.ceil(length_m / HIGHWAY_IMAGE_M_PER_PX))
    image = np.full((height_px, width_px, 3), (0.35, 0.55, 0.3))  # verge
    rows = (np.arange(height_px) + 0.5) * HIGHWAY_IMAGE_M_PER_PX  # (H,) image y of each pixel row [m]
    for markings in (upper, lower):
        image[(rows >= markings[0]) & (rows <= markings[-1])] = (0.42, 0.42, 0.42)
        for y_m in markings:
            image[min(height_px - 1, int(y_m / HIGHWAY_IMAGE_M_PER_PX))] = (1.0, 1.0, 1.0)
    path = Path(directory) / highway_image_file(recording_id)
    pixels = Image.fromarray(np.round(image * 255).astype(np.uint8))  # (H, W, 3) uint8: RGB
    return atomic_write(path, lambda tmp: pixels.save(tmp, format="png"))
