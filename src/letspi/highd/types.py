"""In-memory HighD recording: plain data, no behaviour (reading/writing lives in ``io``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd


@dataclass(frozen=True)
class Recording:
    """One HighD recording.

    Attributes:
        recording_id: the ``NN`` of the file names.
        meta: the single row of ``NN_recordingMeta.csv`` as a dict keyed by HighD column names
            (``upperLaneMarkings``/``lowerLaneMarkings`` kept as the ';'-separated strings).
        tracks_meta: ``NN_tracksMeta.csv``; one row per vehicle, HighD column names.
        tracks: ``NN_tracks.csv``; one row per vehicle per frame, HighD column names,
            sorted by (id, frame).
    """

    recording_id: int
    meta: dict[str, object]
    tracks_meta: pd.DataFrame
    tracks: pd.DataFrame

    @property
    def frame_rate_hz(self) -> float:
        return float(self.meta["frameRate"])  # type: ignore[arg-type]

    @property
    def upper_markings_y_m(self) -> np.ndarray:
        """Upper carriageway lane markings, image y [m], ascending. Shape (M_upper,)."""
        return parse_markings(str(self.meta["upperLaneMarkings"]))

    @property
    def lower_markings_y_m(self) -> np.ndarray:
        """Lower carriageway lane markings, image y [m], ascending. Shape (M_lower,)."""
        return parse_markings(str(self.meta["lowerLaneMarkings"]))


def parse_markings(text: str) -> np.ndarray:
    """Parse a HighD ';'-separated marking list into an ascending float array."""
    values = [float(v) for v in text.split(";") if v.strip()]
    return np.sort(np.asarray(values, dtype=np.float64))


def format_markings(values_m: np.ndarray) -> str:
    return ";".join(f"{v:.2f}" for v in np.sort(np.asarray(values_m, dtype=np.float64)))
