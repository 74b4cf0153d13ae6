"""``NN_events.csv``: scripted traffic events beside a HighD recording (a letspi extension).

HighD itself has no such file; letspi's SUMO generator writes one per recording so that the
critical situations it injected can be found again. One row per event, in the recording's own
frame numbers and vehicle ids:

======================  =====================================================================
column                  meaning
======================  =====================================================================
``frame``               HighD frame (of this recording) at which the event starts
``id``                  HighD id of the acting vehicle (the braking leader, the vehicle cutting
                        in, the truck pulling out)
``kind``                ``hard_brake``, ``cut_in`` or ``truck_pullout``
``other_id``            HighD id of the vehicle it acts on (the follower that must react; for a
                        lane change the vehicle it ends up in front of), 0 = none recorded
``lane_id``             HighD laneId of the actor at the start
``target_lane_id``      laneId the actor changes to (lane changes), else equal to ``lane_id``
``speed_mps``           actor speed at the start [m/s]
``target_speed_mps``    speed the actor brakes to (``hard_brake``), else empty
``decel_mps2``          commanded deceleration (``hard_brake``) [m/s²], else empty
``duration_s``          braking duration (``hard_brake``) or lane-change duration [s]
``gap_m``               bumper-to-bumper gap between ``other_id`` and the actor at the start [m]
``reaction_s``          reaction time of the driver of ``other_id`` [s]
``held_s``              how long ``other_id`` kept its speed from ``frame`` on [s]: until it
                        perceived the event (at once for a braking leader; when the lane
                        changer's centre crossed into its lane, 2 s after the start, for a
                        cut-in) plus its reaction time, or less when released early because
                        avoiding contact would otherwise have needed harder braking than the
                        generator allows; 0 = not held
``other_decel_mps2``    deceleration ``other_id`` then brakes with (``hard_brake``: a share of
                        the leader's, built up at the generator's jerk) until it no longer
                        closes in [m/s²]; empty when SUMO's car following takes over at once
======================  =====================================================================

Empty cells are "not applicable". Events whose actor is not in the recording at the start frame
are not written.
"""

from __future__ import annotations

from pathlib import Path
from typing import Final

import pandas as pd

__all__ = ["EVENTS_COLUMNS", "EVENT_KINDS", "events_file", "read_events", "write_events"]

EVENTS_COLUMNS: Final[tuple[str, ...]] = (
    "frame", "id", "kind", "other_id", "lane_id", "target_lane_id", "speed_mps", "target_speed_mps",
    "decel_mps2", "duration_s", "gap_m", "reaction_s", "held_s", "other_decel_mps2",
)
EVENT_KINDS: Final[tuple[str, ...]] = ("hard_brake", "cut_in", "truck_pullout")
_INT_COLUMNS: Final[tuple[str, ...]] = ("frame", "id", "other_id", "lane_id", "target_lane_id")


def events_file(recording_id: int) -> str:
    return f"{recording_id:02d}_events.csv"


def write_events(events: pd.DataFrame, directory: Path, recording_id: int) -> Path:
    """Write ``NN_events.csv`` (columns :data:`EVENTS_COLUMNS`, sorted by frame, id)."""
    missing = [c for c in EVENTS_COLUMNS if c not in events.columns]
    if missing:
        raise ValueError(f"events are missing columns {missing}")
    out = events[list(EVENTS_COLUMNS)].sort_values(["frame", "id"], kind="stable")
    path = Path(directory) / events_file(recording_id)
    out.to_csv(path, index=False, float_format="%.6f")
    return path


def read_events(directory: Path, recording_id: int) -> pd.DataFrame | None:
    """``NN_events.csv`` of a recording, or ``None`` when there is none (e.g. real HighD data).

    Raises:
        ValueError: naming the file and the column when a column is missing, an integer column
            holds something else, or a kind is unknown.
    """
    path = Path(directory) / events_file(recording_id)
    if not path.exists():
        return None
    frame = pd.read_csv(path)
    missing = [c for c in EVENTS_COLUMNS if c not in frame.columns]
    if missing:
        raise ValueError(f"{path.name}: missing column(s) {missing}")
    for col in _INT_COLUMNS:
        values = pd.to_numeric(frame[col], errors="coerce")
        bad = (values.isna() | (values != values.round())).to_numpy()
        if bad.any():
            line = int(bad.argmax()) + 2  # header is line 1
            value = frame[col].iloc[line - 2]
            raise ValueError(f"{path.name}: column '{col}', line {line}: not an integer ({value!r})")
        frame[col] = values.astype("int64")
    unknown = ~frame["kind"].isin(EVENT_KINDS)
    if unknown.any():
        line = int(unknown.to_numpy().argmax()) + 2
        raise ValueError(f"{path.name}: column 'kind', line {line}: unknown kind {frame['kind'][unknown].iloc[0]!r}")
    return frame[list(EVENTS_COLUMNS)]
