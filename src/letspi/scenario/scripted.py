"""Which neighbours of a scenario act in a scripted event (``NN_events.csv``, ``letspi.highd.events``).

In ``closed-loop-hybrid`` the actors of those events keep their recorded behaviour. A neighbour slot is *scripted*
when its vehicle is the actor (``id``, not ``other_id``) of an event under way in the window's future: starting no
later than its last frame and ending (``duration_s`` + ``EVENT_TAIL_S`` after its start) no earlier than t = 0.
Events match by ``recording_key``, as recording ids repeat.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from letspi.constants import DT_S, N_FUTURE
from letspi.highd.events import events_file, read_events
from letspi.highd.io import list_recording_ids, read_recording_meta
from letspi.scenario.extract import recording_key_of
from letspi.scenario.types import ScenarioBatch

EVENT_TAIL_S = 4.0


def recording_events(directory: Path) -> dict[str, pd.DataFrame]:
    """``recording_key`` -> ``NN_events.csv`` rows of every recording in ``directory`` that has one."""
    directory = Path(directory)
    out: dict[str, pd.DataFrame] = {}
    for rid in list_recording_ids(directory):
        if not (directory / events_file(rid)).exists():
            continue
        events = read_events(directory, rid)
        if events is not None:
            out[recording_key_of(*read_recording_meta(directory, rid))] = events
    return out


def scripted_neighbours(batch: ScenarioBatch, events: Mapping[str, pd.DataFrame]) -> np.ndarray:
    """(B, N) bool: neighbour slots whose vehicle acts in an event under way in the window's future; ``events``:
    ``recording_key`` -> events table (``recording_events``)."""
    out = np.zeros(batch.nbr_id.shape, dtype=bool)
    keys = np.asarray(batch.recording_key).astype(str)
    for key in np.unique(keys):
        ev = events.get(str(key))
        if ev is None or not len(ev):
            continue
        rows = np.flatnonzero(keys == key)
        start = ev["frame"].to_numpy(np.int64)
        duration_s = np.nan_to_num(ev["duration_s"].to_numpy(np.float64), nan=0.0)
        end = start + np.ceil((duration_s + EVENT_TAIL_S) / DT_S).astype(np.int64)
        actor = ev["id"].to_numpy(np.int64)
        t0 = np.asarray(batch.frame0, dtype=np.int64)[rows]  # HighD frame at t = 0
        under_way = (start[None, :] <= t0[:, None] + N_FUTURE) & (end[None, :] >= t0[:, None])  # (R, E)
        ids = np.asarray(batch.nbr_id, dtype=np.int64)[rows]  # (R, N); 0 = empty slot, never an actor
        acts = (ids[:, :, None] == actor[None, None, :]) & under_way[:, None, :]  # (R, N, E)
        out[rows] = acts.any(axis=2) & (ids > 0)
    return out
