"""build_recording: derived HighD columns against hand-computed values (see highd_samples)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from highd_samples import LOWER_MARKINGS, UPPER_MARKINGS, sample_recording, sample_states, synthetic_states

from letspi.highd.derive import build_recording
from letspi.highd.io import validate_recording
from letspi.highd.schema import TRACKS_COLUMNS, TRACKS_META_COLUMNS
from letspi.highd.types import Recording


@pytest.fixture(scope="module")
def rec() -> Recording:
    return sample_recording()


def _row(rec: Recording, vid: int, frame: int) -> pd.Series:
    t = rec.tracks
    rows = t[(t["id"] == vid) & (t["frame"] == frame)]
    assert len(rows) == 1
    return rows.iloc[0]


def test_columns_order_and_sorting(rec: Recording) -> None:
    assert tuple(rec.tracks.columns) == TRACKS_COLUMNS
    assert tuple(rec.tracks_meta.columns) == TRACKS_META_COLUMNS
    keys = rec.tracks[["id", "frame"]].to_numpy()
    assert np.all(np.lexsort((keys[:, 1], keys[:, 0])) == np.arange(len(keys)))
    validate_recording(rec)  # a built recording is valid HighD


def test_lane_ids_at_hand_computed_positions(rec: Recording) -> None:
    # 3+3 road: markings 10, 13.5, 17, 20.5 | 24, 27.5, 31, 34.5 -> lanes 2-4 and 6-8
    expected = {1: 7, 2: 7, 3: 8, 4: 6, 10: 3, 11: 3, 12: 4}
    for vid, lane in expected.items():
        assert _row(rec, vid, 1)["laneId"] == lane, vid


def test_lane_change_and_count(rec: Recording) -> None:
    t = rec.tracks[rec.tracks["id"] == 5]
    # centre y crosses the marking at y = 31.0 between frames 24 and 25
    assert set(t.loc[t["frame"] <= 24, "laneId"]) == {8}
    assert set(t.loc[t["frame"] >= 25, "laneId"]) == {7}
    n_changes = rec.tracks_meta.set_index("id")["numLaneChanges"]
    assert n_changes[5] == 1
    assert (n_changes.drop(5) == 0).all()


NEIGHBOURS_FRAME_1 = {
    # id: (preceding, following, leftPrec, leftAlong, leftFoll, rightPrec, rightAlong, rightFoll)
    1: (2, 0, 0, 4, 0, 3, 0, 0),
    2: (0, 1, 0, 0, 4, 0, 0, 3),
    3: (0, 0, 2, 0, 1, 0, 0, 0),
    4: (0, 0, 0, 0, 0, 2, 1, 0),
    10: (0, 11, 0, 0, 12, 0, 0, 0),  # direction 1: left = larger y = lane 4
    11: (10, 0, 12, 0, 0, 0, 0, 0),
    12: (0, 0, 0, 0, 0, 10, 0, 11),
}
NEIGHBOUR_COLUMNS = [
    "precedingId",
    "followingId",
    "leftPrecedingId",
    "leftAlongsideId",
    "leftFollowingId",
    "rightPrecedingId",
    "rightAlongsideId",
    "rightFollowingId",
]


@pytest.mark.parametrize("vid", sorted(NEIGHBOURS_FRAME_1))
def test_neighbour_ids_in_hand_made_frame(rec: Recording, vid: int) -> None:
    row = _row(rec, vid, 1)
    assert tuple(int(row[c]) for c in NEIGHBOUR_COLUMNS) == NEIGHBOURS_FRAME_1[vid]


def test_lane_changer_gets_new_leader_and_follower(rec: Recording) -> None:
    assert _row(rec, 5, 24)["precedingId"] == 3  # truck ahead in lane 8
    assert _row(rec, 5, 25)["precedingId"] == 1  # car 1 ahead in lane 7
    assert _row(rec, 1, 25)["followingId"] == 5
    assert _row(rec, 3, 24)["followingId"] == 5
    assert _row(rec, 3, 25)["followingId"] == 0


def test_dhw_thw_ttc_direction_2(rec: Recording) -> None:
    row = _row(rec, 1, 1)
    # car 1 front bumper 50 + 4.5 = 54.5, car 2 rear bumper 80 -> gap 25.5 m, closing 30 - 25 = 5 m/s
    assert row["dhw"] == pytest.approx(25.5)
    assert row["thw"] == pytest.approx(25.5 / 30.0)
    assert row["ttc"] == pytest.approx(25.5 / 5.0)
    assert row["precedingXVelocity"] == pytest.approx(25.0)
    # leader has nothing ahead: HighD's zeros
    lead = _row(rec, 2, 1)
    assert (lead["dhw"], lead["thw"], lead["ttc"], lead["precedingXVelocity"]) == (0.0, 0.0, 0.0, 0.0)


def test_dhw_thw_ttc_direction_1(rec: Recording) -> None:
    row = _row(rec, 11, 1)
    # towards -x: car 10 rear bumper at x = 304.5, car 11 front bumper at x = 330
    assert row["dhw"] == pytest.approx(25.5)
    assert row["thw"] == pytest.approx(25.5 / 32.0)
    assert row["ttc"] == pytest.approx(25.5 / 2.0)
    assert row["precedingXVelocity"] == pytest.approx(-30.0)


def test_ttc_zero_when_opening(rec: Recording) -> None:
    # car 5 (28 m/s) behind car 1 (30 m/s) after its lane change: gap opens
    row = _row(rec, 5, 30)
    assert row["precedingId"] == 1 and row["dhw"] > 0
    assert row["ttc"] == 0.0


def test_sight_distances(rec: Recording) -> None:
    # section: min x = 10 (car 5 enters), max x + width = 334.5 (car 11 at frame 1)
    car1 = _row(rec, 1, 1)
    assert car1["frontSightDistance"] == pytest.approx(334.5 - 54.5)
    assert car1["backSightDistance"] == pytest.approx(50.0 - 10.0)
    car10 = _row(rec, 10, 1)  # travels towards -x: front bumper at x = 300
    assert car10["frontSightDistance"] == pytest.approx(300.0 - 10.0)
    assert car10["backSightDistance"] == pytest.approx(334.5 - 304.5)


def test_tracks_meta_values(rec: Recording) -> None:
    tm = rec.tracks_meta.set_index("id")
    assert list(tm.index) == [1, 2, 3, 4, 5, 10, 11, 12]
    assert tm.loc[3, "class"] == "Truck"
    assert (tm.loc[3, "width"], tm.loc[3, "height"]) == (15.0, 2.5)
    assert tuple(tm.loc[5, ["initialFrame", "finalFrame", "numFrames"]]) == (5, 50, 46)
    assert tm.loc[10, "drivingDirection"] == 1 and tm.loc[1, "drivingDirection"] == 2
    assert tm.loc[1, "traveledDistance"] == pytest.approx(49 * 30.0 / 25)
    # speeds are positive in both directions
    assert [tm.loc[11, c] for c in ("minXVelocity", "maxXVelocity", "meanXVelocity")] == pytest.approx([32, 32, 32])
    # car 1 closes on car 2 at 5 m/s for 49 frames: 25.5 - 5 * 49 / 25 = 15.7 m
    assert tm.loc[1, "minDHW"] == pytest.approx(15.7)
    assert tm.loc[1, "minTHW"] == pytest.approx(15.7 / 30.0)
    assert tm.loc[1, "minTTC"] == pytest.approx(15.7 / 5.0)
    # no preceding vehicle ever: -1
    assert tuple(tm.loc[2, ["minDHW", "minTHW", "minTTC"]]) == (-1.0, -1.0, -1.0)


def test_recording_meta(rec: Recording) -> None:
    m = rec.meta
    assert (m["id"], m["frameRate"], m["locationId"], m["speedLimit"]) == (1, 25, 2, 33.33)
    assert (m["month"], m["weekDay"], m["startTime"]) == ("09", "Tue", "10:15")
    assert m["duration"] == pytest.approx(2.0)
    assert (m["numVehicles"], m["numCars"], m["numTrucks"]) == (8, 7, 1)
    assert m["totalDrivenTime"] == pytest.approx((7 * 50 + 46) / 25)
    assert m["totalDrivenDistance"] == pytest.approx(rec.tracks_meta["traveledDistance"].sum())
    assert m["upperLaneMarkings"] == "10.00;13.50;17.00;20.50"
    assert rec.lower_markings_y_m.tolist() == [24.0, 27.5, 31.0, 34.5]


def test_input_order_does_not_matter() -> None:
    states, vehicles = sample_states()
    a = sample_recording()
    b = build_recording(
        states.iloc[::-1],
        vehicles.iloc[::-1],
        recording_id=1,
        upper_markings_y_m=[20.5, 17.0, 13.5, 10.0],
        lower_markings_y_m=[24.0, 27.5, 31.0, 34.5],
        location_id=2,
        speed_limit_mps=33.33,
        month="09",
        week_day="Tue",
        start_time="10:15",
    )
    pd.testing.assert_frame_equal(a.tracks, b.tracks)
    pd.testing.assert_frame_equal(a.tracks_meta, b.tracks_meta)
    assert a.meta == b.meta


def _build(states: pd.DataFrame, vehicles: pd.DataFrame) -> Recording:
    return build_recording(
        states, vehicles, recording_id=1, upper_markings_y_m=[10, 13.5], lower_markings_y_m=[24, 27.5]
    )


def test_rejects_bad_inputs() -> None:
    states, vehicles = sample_states()
    with pytest.raises(ValueError, match="consecutive"):
        _build(states[~((states["id"] == 1) & (states["frame"] == 10))], vehicles)
    with pytest.raises(ValueError, match="not in vehicles"):
        _build(states, vehicles[vehicles["id"] != 3])
    with pytest.raises(ValueError, match="missing columns"):
        _build(states.drop(columns=["yVelocity"]), vehicles)
    bad = vehicles.copy()
    bad.loc[0, "class"] = "Bus"
    with pytest.raises(ValueError, match="class"):
        _build(states, bad)


def test_vectorised_build_is_fast_enough() -> None:
    import time

    states, vehicles = synthetic_states(400, 250)  # 100k rows
    t0 = time.perf_counter()
    rec = build_recording(
        states, vehicles, recording_id=3, upper_markings_y_m=UPPER_MARKINGS, lower_markings_y_m=LOWER_MARKINGS
    )
    elapsed = time.perf_counter() - t0
    assert len(rec.tracks) == 100_000
    assert elapsed < 5.0  # generous: the machine is shared; measured ~0.4 s
    validate_recording(rec)
