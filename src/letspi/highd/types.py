"""In-memory HighD recording: plain data, no behaviour (reading/writing lives in ``io``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd


@dataclass(frozen=True)
class Recording:
    """One HighD recording, HighD column names throughout. ``meta``: the one row of ``NN_recordingMeta.csv`` (lane
    markings kept as ';'-separated strings); ``tracks_meta``: one row per vehicle; ``tracks``: one row per vehicle per
    frame, sorted by (id, frame)."""

    recording_id: int
    meta: dict[str, object]
    tracks_meta: pd.DataFrame
    tracks: pd.DataFrame

    @property
    def frame_rate_hz(self) -> float:
        return float(self.meta["frameRate"])  # type: ignore[arg-type]

    @property
    def upper_markings_y_m(self) -> np.ndarray:
        """Upper carriageway markings, image y [m], ascending, (M_upper,)."""
        return parse_markings(str(self.meta["upperLaneMarkings"]))

    @property
    def lower_markings_y_m(self) -> np.ndarray:
        """Lower carriageway markings, image y [m], ascending, (M_lower,)."""
        return parse_markings(str(self.meta["lowerLaneMarkings"]))


def parse_markings(text: str) -> np.ndarray:
    """A ';'-separated HighD marking list as an ascending float array."""
    values = [float(v) for v in text.split(";") if v.strip()]
    return np.sort(np.asarray(values, dtype=np.float64))


def format_markings(values_m: np.ndarray) -> str:
    return ";".join(f"{v:.2f}" for v in np.sort(np.asarray(values_m, dtype=np.float64)))
