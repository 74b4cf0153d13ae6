"""closed-loop-hybrid without SUMO: the hand-over rule, the scripted-neighbour mask and the keys."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from highd_samples import sample_recording

from letspi.constants import N_FUTURE
from letspi.evaluation.closed_loop import ClosedLoopSetupError, mode_settings, scripted_for
from letspi.highd.events import EVENTS_COLUMNS, write_events
from letspi.highd.io import read_recording, write_recording
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.extract import recording_key
from letspi.scenario.scripted import EVENT_TAIL_S, recording_events, scripted_neighbours
from letspi.simulation.config import ClosedLoopConfig, HandoverConfig
from letspi.simulation.handover import within_reach

MARKINGS = np.array([[0.0, 3.75, 7.5, 11.25]])  # three lanes: centres 1.875, 5.625, 9.375
EGO_LEN, EGO_WID = 4.5, 1.8


def _reach(ego_xy: tuple[float, float], nbr_xy: list[tuple[float, float]], lanes: int = 0,
           behind_m: float = 0.0) -> list[bool]:
    nbr = np.array([nbr_xy], dtype=float)
    out = within_reach(np.array([ego_xy]), np.array([EGO_LEN]), np.array([EGO_WID]), nbr,
                       np.full(nbr.shape[:2], 4.5), MARKINGS, HandoverConfig(lanes=lanes, behind_m=behind_m))
    return out[0].tolist()


def test_only_vehicles_fully_behind_in_a_lane_the_ego_covers_are_within_reach() -> None:
    ego = (0.0, 5.625)  # middle lane; rear bumper at x = -2.25
    nbrs = [
        (-20.0, 5.625),  # same lane, behind
        (-4.5, 5.625),  # same lane, front bumper exactly at the ego's rear bumper: fully behind
        (-4.0, 5.625),  # same lane, front bumper 0.5 m beside the ego's rear: not behind
        (30.0, 5.625),  # same lane, ahead
        (-20.0, 9.375),  # left lane, behind
        (-20.0, 1.875),  # right lane, behind
        (-20.0, 13.0),  # off the road
        (np.nan, np.nan),  # absent
    ]
    assert _reach(ego, nbrs) == [True, True, False, False, False, False, False, False]
    # lanes = 1: the adjacent lanes as well (the literal "ego's lane or an adjacent lane")
    assert _reach(ego, nbrs, lanes=1) == [True, True, False, False, True, True, False, False]
    # behind_m: the front bumper must be that far behind the ego's rear bumper
    assert _reach(ego, [(-20.0, 5.625), (-8.0, 5.625)], behind_m=5.0) == [True, False]


def test_a_lane_change_brings_the_target_lane_within_reach_when_the_box_enters_it() -> None:
    follower_left = [(-20.0, 9.375)]
    assert _reach((0.0, 6.5), follower_left) == [False]  # box edge at 7.4 m: still in its lane
    assert _reach((0.0, 6.7), follower_left) == [True]  # box edge at 7.6 m: over the marking at 7.5 m
    # an ego beyond the left road edge covers the edge lane
    assert _reach((0.0, 12.5), follower_left) == [True]
    assert _reach((0.0, 12.5), [(-20.0, 5.625)]) == [False]


def _events(rows: list[dict[str, object]]) -> pd.DataFrame:
    base = {c: 0 for c in EVENTS_COLUMNS} | {"kind": "hard_brake", "duration_s": 2.0}
    return pd.DataFrame([base | r for r in rows])


def test_actors_of_events_under_way_in_the_window_future_are_scripted() -> None:
    nbrs = [VehicleSpec(x0_m=30.0 + 10 * i, speed_mps=30.0) for i in range(4)]  # ids 2, 3, 4, 5
    batch = straight_road_scenario(neighbours=nbrs)
    t0 = int(batch.frame0[0])  # HighD frame at t = 0
    tail = int(np.ceil((2.0 + EVENT_TAIL_S) / 0.04))  # frames an event with duration_s = 2 lasts
    events = _events([
        {"id": 2, "other_id": 3, "frame": t0 + N_FUTURE},  # starts on the window's last frame: scripted
        {"id": 4, "frame": t0 + N_FUTURE + 1},  # starts after the window: not scripted
        {"id": 5, "frame": t0 - tail},  # ends exactly at t = 0: scripted
        {"id": 99, "frame": t0},  # a vehicle not among the neighbours
    ])  # fmt: skip
    mask = scripted_neighbours(batch, {"synthetic": events})
    # slot 1 (id 3) is only acted on: its reaction should answer the simulation, not the log
    assert mask[0, :4].tolist() == [True, False, False, True]
    assert not mask[0, 4:].any()  # empty slots (id 0) never
    ended = _events([{"id": 5, "frame": t0 - tail - 1}])
    assert not scripted_neighbours(batch, {"synthetic": ended}).any()
    assert not scripted_neighbours(batch, {"another-recording": events}).any()  # matched by recording_key


def test_events_are_matched_to_recordings_by_content_key(tmp_path: Path) -> None:
    rec = sample_recording(recording_id=3)
    write_recording(rec, tmp_path)
    ids = rec.tracks_meta["id"].to_numpy()
    write_events(_events([{"id": int(ids[0]), "frame": 10}]), tmp_path, 3)
    found = recording_events(tmp_path)
    key = recording_key(read_recording(tmp_path, 3))  # the key scenarios cut from these files carry
    assert list(found) == [key]  # computed from the two meta files only
    assert found[key]["id"].tolist() == [int(ids[0])]


def test_scripted_for_refuses_a_directory_of_another_dataset(tmp_path: Path) -> None:
    rec = sample_recording(recording_id=1)
    write_recording(rec, tmp_path)
    write_events(_events([{"id": 2, "frame": 10}]), tmp_path, 1)
    batch = straight_road_scenario(neighbours=[VehicleSpec(x0_m=30.0, speed_mps=30.0)])  # key "synthetic"
    with pytest.raises(ClosedLoopSetupError, match="no NN_events.csv of the scenarios' recordings"):
        scripted_for(batch, tmp_path)
    none = scripted_for(batch, tmp_path, required=False)  # found through provenance: no events, no error
    assert none.source is None and not none.mask.any()
    ours = replace(batch, recording_key=np.array([recording_key(read_recording(tmp_path, 1))], dtype=object))
    assert scripted_for(ours, tmp_path).matched == 1


def test_hybrid_keys_hold_the_driver_model_the_hand_over_rule_and_the_scripted_mask() -> None:
    mask = np.zeros((3, 8), dtype=bool)
    mask[1, 2] = True
    hybrid = mode_settings(ClosedLoopConfig("closed-loop-hybrid"), mask)
    assert hybrid["driver"]["decel_mps2"] == 3.0
    assert hybrid["handover"] == {"lanes": 0, "behind_m": 0.0, "follow_log_speed": True}
    assert hybrid["scripted"]["n"] == 1
    other = mask.copy()
    other[1, 2], other[2, 2] = False, True
    assert mode_settings(ClosedLoopConfig("closed-loop-hybrid"), other)["scripted"] != hybrid["scripted"]
    assert mode_settings(ClosedLoopConfig("closed-loop-hybrid"), None)["scripted"] == {"n": 0, "digest": "none"}
    wider = mode_settings(ClosedLoopConfig("closed-loop-hybrid", handover=HandoverConfig(lanes=1)), mask)
    assert wider["handover"]["lanes"] == 1
    reactive = mode_settings(ClosedLoopConfig("closed-loop-reactive"), mask)
    assert "driver" in reactive and "handover" not in reactive and "scripted" not in reactive
    log = mode_settings(ClosedLoopConfig("closed-loop-log"), mask)
    assert "driver" not in log and "handover" not in log


def test_handover_settings_are_checked() -> None:
    with pytest.raises(ValueError, match="lanes"):
        HandoverConfig(lanes=-1)
    with pytest.raises(ValueError, match="behind_m"):
        HandoverConfig(behind_m=-1.0)
    assert ClosedLoopConfig(mode="closed-loop-hybrid").mode.has_drivers  # type: ignore[arg-type]
