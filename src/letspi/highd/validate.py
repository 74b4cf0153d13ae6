"""Semantic validation of parsed HighD tables, shared by reading and writing (``letspi.highd.io``).

Every value and every cross-file relation is checked, vectorised; each check raises a ``HighDFormatError``
naming the file, the column and the 1-based CSV line (``line_of`` maps a 0-based row to it). A vehicle whose
sizes disagree from its first track row on is blamed on tracksMeta; ``laneId`` must be a lane of the markings
(1 .. M + 1) on the vehicle's own carriageway; neighbour ids are 0 or another vehicle of tracksMeta.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np
import pandas as pd

from letspi.highd.errors import HighDFormatError
from letspi.highd.schema import DRIVING_DIRECTION_LOWER, DRIVING_DIRECTION_UPPER, VEHICLE_CLASSES
from letspi.highd.types import parse_markings

#: Maps a 0-based data-row position to the 1-based CSV line number (header = line 1).
LineOf = Callable[[int], int]

NEIGHBOUR_COLUMNS = (
    "precedingId", "followingId", "leftPrecedingId", "leftAlongsideId", "leftFollowingId",
    "rightPrecedingId", "rightAlongsideId", "rightFollowingId",
)  # fmt: skip
#: Sizes in tracks and tracksMeta are written with 2 decimals from the same value.
_SIZE_TOLERANCE_M = 1e-6


def _first(mask: np.ndarray) -> int | None:
    return int(np.argmax(mask)) if mask.any() else None


def markings_of(path: Path, meta: pd.DataFrame, line_of: LineOf) -> tuple[np.ndarray, np.ndarray]:
    """The upper and lower markings (ascending image y), at least two each, finite, the upper above the lower."""
    row = meta.iloc[0]
    out = []
    for col in ("upperLaneMarkings", "lowerLaneMarkings"):
        try:
            values = parse_markings(str(row[col]))
        except ValueError as exc:
            raise HighDFormatError(
                path, f"not a ';'-separated list of numbers ({row[col]!r})", column=col, line=line_of(0)
            ) from exc
        if not np.isfinite(values).all():
            raise HighDFormatError(path, f"markings must be finite numbers ({row[col]!r})", column=col, line=line_of(0))
        if len(values) < 2:
            raise HighDFormatError(
                path, f"needs at least 2 markings (the road edges), got {len(values)}", column=col, line=line_of(0)
            )
        out.append(values)
    upper, lower = out
    if upper[-1] > lower[0]:
        raise HighDFormatError(
            path,
            f"the upper carriageway's markings must lie above (smaller y than) the lower one's "
            f"(max {upper[-1]:g} > min {lower[0]:g})",
            column="upperLaneMarkings",
            line=line_of(0),
        )
    return upper, lower


def validate_recording_meta(meta: pd.DataFrame, recording_id: int, path: Path, line_of: LineOf) -> None:
    if len(meta) != 1:
        raise HighDFormatError(path, f"expected exactly one data row, found {len(meta)}", line=line_of(1))
    row = meta.iloc[0]
    if int(row["id"]) != recording_id:
        raise HighDFormatError(
            path,
            f"id {int(row['id'])} does not match the file name ({recording_id:02d})",
            column="id",
            line=line_of(0),
        )
    if int(row["frameRate"]) <= 0:
        raise HighDFormatError(path, "frameRate must be positive", column="frameRate", line=line_of(0))
    limit = float(row["speedLimit"])
    if limit != -1.0 and limit <= 0:
        raise HighDFormatError(
            path, f"speedLimit must be -1 (none) or positive, got {limit:g}", column="speedLimit", line=line_of(0)
        )
    for col in ("numVehicles", "numCars", "numTrucks"):
        if (count := int(row[col])) < 0:
            raise HighDFormatError(path, f"{col} must not be negative, got {count}", column=col, line=line_of(0))
    markings_of(path, meta, line_of)


def validate_tracks_meta(tm: pd.DataFrame, path: Path, line_of: LineOf) -> None:
    ids = tm["id"].to_numpy()
    _check(ids <= 0, path, "id", line_of, lambda k: f"vehicle id must be positive, got {ids[k]}")
    _check(pd.Series(ids).duplicated().to_numpy(), path, "id", line_of, lambda k: f"duplicated vehicle id {ids[k]}")
    _check(~tm["class"].isin(VEHICLE_CLASSES).to_numpy(), path, "class", line_of,
           lambda k: f"unknown class {tm['class'].iloc[k]!r} (expected one of {list(VEHICLE_CLASSES)})")
    direction = tm["drivingDirection"].to_numpy()
    _check((direction != DRIVING_DIRECTION_UPPER) & (direction != DRIVING_DIRECTION_LOWER), path, "drivingDirection",
           line_of, lambda k: f"drivingDirection must be 1 or 2, got {direction[k]}")
    for col in ("width", "height"):
        values = tm[col].to_numpy()
        _check(~(values > 0), path, col, line_of, partial(_not_positive, ids, col, values))
    first, last, n = (tm[c].to_numpy() for c in ("initialFrame", "finalFrame", "numFrames"))
    _check(first < 1, path, "initialFrame", line_of,
           lambda k: f"vehicle {ids[k]}: frames start at 1, got initialFrame {first[k]}")
    _check(n != last - first + 1, path, "numFrames", line_of,
           lambda k: f"vehicle {ids[k]}: numFrames {n[k]} != finalFrame - initialFrame + 1 = {last[k] - first[k] + 1}")
    changes = tm["numLaneChanges"].to_numpy()
    _check(changes < 0, path, "numLaneChanges", line_of,
           lambda k: f"numLaneChanges must not be negative, got {changes[k]}")


def _not_positive(ids: np.ndarray, col: str, values: np.ndarray, k: int) -> str:
    return f"vehicle {ids[k]}: {col} must be positive, got {values[k]:g}"


def _check(bad: np.ndarray, path: Path, column: str, line_of: LineOf, message: Callable[[int], str]) -> None:
    """``HighDFormatError`` at the first row where ``bad`` holds, saying ``message(row)``."""
    if (k := _first(bad)) is not None:
        raise HighDFormatError(path, message(k), column=column, line=line_of(k))


def validate_counts(meta: pd.DataFrame, tm: pd.DataFrame, path: Path, line_of: LineOf, tm_path: Path) -> None:
    """recordingMeta's vehicle counts against tracksMeta's rows and classes."""
    row = meta.iloc[0]
    expected = {
        "numVehicles": (len(tm), "vehicles"),
        "numCars": (int((tm["class"] == "Car").sum()), "cars"),
        "numTrucks": (int((tm["class"] == "Truck").sum()), "trucks"),
    }
    for col, (count, what) in expected.items():
        if int(row[col]) != count:
            raise HighDFormatError(
                path, f"{col} is {int(row[col])} but {tm_path.name} has {count} {what}", column=col, line=line_of(0)
            )


def _check_sizes(
    tracks: pd.DataFrame, tm: pd.DataFrame, starts: np.ndarray, path: Path, meta_path: Path,
    line_of: LineOf, meta_line_of: LineOf,
) -> None:  # fmt: skip
    ids = tracks["id"].to_numpy()
    meta_row = pd.Index(tm["id"].to_numpy()).get_indexer(ids)  # every id is known by now
    for col in ("width", "height"):
        values = tracks[col].to_numpy()
        _check(~(values > 0), path, col, line_of, partial(_not_positive, ids, col, values))
        expected = tm[col].to_numpy()[meta_row]
        bad = np.abs(values - expected) > _SIZE_TOLERANCE_M
        if (k := _first(bad)) is None:
            continue
        start = starts[np.searchsorted(starts, k, side="right") - 1]
        if bad[start]:  # the whole vehicle disagrees from its first row on: blame tracksMeta
            m = int(meta_row[k])
            raise HighDFormatError(
                meta_path,
                f"vehicle {ids[k]}: {col} is {expected[k]:g} but {path.name} has {values[k]:g}",
                column=col,
                line=meta_line_of(m),
            )
        raise HighDFormatError(
            path,
            f"vehicle {ids[k]}: {col} {values[k]:g} differs from {expected[k]:g} in {meta_path.name}",
            column=col,
            line=line_of(k),
        )


def _check_lanes(
    tracks: pd.DataFrame, tm: pd.DataFrame, n_upper: int, n_lower: int, path: Path, line_of: LineOf
) -> None:
    lanes = tracks["laneId"].to_numpy()
    top = n_upper + n_lower + 1
    if (k := _first((lanes < 1) | (lanes > top))) is not None:
        raise HighDFormatError(
            path,
            f"laneId {lanes[k]} does not exist on this road (lanes 1..{top} from {top - 1} markings)",
            column="laneId",
            line=line_of(k),
        )
    ids = tracks["id"].to_numpy()
    direction = tm.set_index("id")["drivingDirection"].reindex(ids).to_numpy()
    median = n_upper + 1  # between the carriageways
    wrong_side = ((direction == DRIVING_DIRECTION_UPPER) & (lanes > median)) | (
        (direction == DRIVING_DIRECTION_LOWER) & (lanes < median)
    )
    if (k := _first(wrong_side)) is not None:
        side = "lower" if lanes[k] > median else "upper"
        raise HighDFormatError(
            path,
            f"vehicle {ids[k]} (drivingDirection {direction[k]}) is in lane {lanes[k]} of the {side} carriageway",
            column="laneId",
            line=line_of(k),
        )


def _check_neighbours(tracks: pd.DataFrame, meta_ids: np.ndarray, path: Path, meta_path: Path, line_of: LineOf) -> None:
    ids = tracks["id"].to_numpy()
    for col in NEIGHBOUR_COLUMNS:
        other = tracks[col].to_numpy()
        if (k := _first((other != 0) & ~np.isin(other, meta_ids))) is not None:
            raise HighDFormatError(
                path, f"{col} {other[k]} is neither 0 nor a vehicle of {meta_path.name}", column=col, line=line_of(k)
            )
        if (k := _first(other == ids)) is not None:
            raise HighDFormatError(path, f"vehicle {ids[k]} is its own {col}", column=col, line=line_of(k))


def validate_tracks(
    tracks: pd.DataFrame,
    tm: pd.DataFrame,
    markings: tuple[np.ndarray, np.ndarray],
    path: Path,
    meta_path: Path,
    line_of: LineOf,
    meta_line_of: LineOf,
) -> None:
    """Check tracks (already sorted by (id, frame)) against tracksMeta and the road."""
    ids = tracks["id"].to_numpy()
    frames = tracks["frame"].to_numpy()
    meta_ids = tm["id"].to_numpy()
    if (k := _first(~np.isin(ids, meta_ids))) is not None:
        raise HighDFormatError(path, f"vehicle id {ids[k]} is not in {meta_path.name}", column="id", line=line_of(k))
    if (k := _first(frames < 1)) is not None:
        raise HighDFormatError(path, f"frames start at 1, got {frames[k]}", column="frame", line=line_of(k))
    same = ids[1:] == ids[:-1]
    step = np.diff(frames)
    if (j := _first(same & (step != 1))) is not None:
        k = j + 1
        what = "repeats" if step[j] == 0 else f"follows frame {frames[j]}"
        raise HighDFormatError(
            path,
            f"frame {frames[k]} of vehicle {ids[k]} {what} (frames per vehicle must be consecutive)",
            column="frame",
            line=line_of(k),
        )
    starts = np.flatnonzero(np.r_[True, ~same])
    ends = np.r_[starts[1:], len(ids)] - 1
    observed = pd.DataFrame(
        {"initialFrame": frames[starts], "finalFrame": frames[ends], "numFrames": ends - starts + 1},
        index=ids[starts],
    )
    # reindex on meta ids: a meta vehicle without any track row gets NaN and fails below
    observed = observed.reindex(meta_ids)
    for col in ("initialFrame", "finalFrame", "numFrames"):
        expected = tm[col].to_numpy()
        got = observed[col].to_numpy(dtype=np.float64)
        if (k := _first(~(got == expected))) is not None:
            if np.isnan(got[k]):
                reason = f"vehicle {meta_ids[k]} has no rows in {path.name}"
            else:
                reason = f"vehicle {meta_ids[k]}: {col} is {expected[k]} but {path.name} has {int(got[k])}"
            raise HighDFormatError(meta_path, reason, column=col, line=meta_line_of(k))
    _check_sizes(tracks, tm, starts, path, meta_path, line_of, meta_line_of)
    _check_lanes(tracks, tm, len(markings[0]), len(markings[1]), path, line_of)
    _check_neighbours(tracks, meta_ids, path, meta_path, line_of)
