"""``NN_events.csv``: scripted traffic events beside a HighD recording (a letspi extension; real HighD has none).

One row per event whose actor is in the recording at the start frame, in its frames and ids; empty cells are
"not applicable". Columns (units as named):

- ``frame`` start; ``id`` the actor (braking leader, car cutting in, truck pulling out); ``kind`` (``EVENT_KINDS``);
  ``other_id`` the vehicle that must react (after a lane change: the one behind), 0 = none.
- ``lane_id``, ``target_lane_id``: the actor's laneId at the start and after its lane change (else equal);
  ``speed_mps`` at the start; ``target_speed_mps``, ``decel_mps2`` of a ``hard_brake``; ``duration_s`` of the
  braking or lane change; ``gap_m`` bumper gap other -> actor at the start; ``reaction_s`` of ``other_id``.
- ``held_s``: how long ``other_id`` kept its speed from ``frame`` on: until it perceived the event (a braking leader
  at once, a cut-in when the changer's centre crossed into its lane) plus its reaction time, or less (released
  early rather than brake harder than allowed; 0 = not held); ``other_decel_mps2``: its braking after that until it
  no longer closes in (``hard_brake``: a share of the leader's, at the generator's jerk; empty: SUMO took over).
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
    """``NN_events.csv`` of a recording, or None when there is none (e.g. real HighD data). ValueError naming the file,
    column and line: a missing column, a non-integer in an integer column, an unknown kind."""
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
