"""Criticality profile, box contacts and the events file, on hand-built recordings."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from letspi.highd.contacts import overlapping_boxes
from letspi.highd.criticality import criticality_profile, profile_directory, profile_table, vehicle_criticality
from letspi.highd.derive import build_recording
from letspi.highd.events import EVENTS_COLUMNS, read_events, write_events
from letspi.highd.io import write_recording
from letspi.highd.types import Recording

UPPER = (10.0, 13.5, 17.0, 20.5)  # lanes 2, 3, 4 (direction 1)
LOWER = (24.0, 27.5, 31.0, 34.5)  # lanes 6, 7, 8 (direction 2)
DT = 0.04
N_FRAMES = 50  # t = 0 .. 1.96 s


def _track(vid: int, length: float, rear_x0: float, vx: float, centre_y: float, width: float = 1.8) -> pd.DataFrame:
    """Constant-velocity box; ``rear_x0`` is the rear bumper x (direction 2) at frame 1."""
    t = np.arange(N_FRAMES) * DT
    x = rear_x0 + vx * t
    return pd.DataFrame({"frame": np.arange(1, N_FRAMES + 1), "id": vid, "x": x, "y": centre_y - width / 2,
                         "width": length, "height": width, "xVelocity": vx, "yVelocity": 0.0,
                         "xAcceleration": 0.0, "yAcceleration": 0.0})


def _pair_recording() -> Recording:
    """Direction 2, lane 7 (centre y 29.25): follower 1 closes in on leader 2; car 3 alone in lane 6.

    Follower front = 70 + 30 t (box x = 65.5 + 30 t, 4.5 m), leader rear = 100 + 25 t:
    gap(t) = 30 - 5 t, smallest at the last frame (t = 1.96 s): 20.2 m.
    Lane 8: car 4 follows truck 5 at the same speed (gap 12.5 m, no closing).
    """
    states = pd.concat([
        _track(1, 4.5, 65.5, 30.0, 29.25),
        _track(2, 4.5, 100.0, 25.0, 29.25),
        _track(3, 4.5, 40.0, 33.0, 25.75),
        _track(4, 4.5, 200.0, 24.0, 32.75),
        _track(5, 15.0, 217.0, 24.0, 32.75, width=2.5),
    ], ignore_index=True)
    vehicles = pd.DataFrame({"id": [1, 2, 3, 4, 5], "class": ["Car", "Car", "Car", "Car", "Truck"],
                             "drivingDirection": [2, 2, 2, 2, 2]})
    return build_recording(states, vehicles, recording_id=1, upper_markings_y_m=UPPER, lower_markings_y_m=LOWER)


def test_tracks_meta_minima_match_highd_definitions() -> None:
    """minDHW / minTHW / minTTC as HighD defines them, against hand-computed values."""
    meta = _pair_recording().tracks_meta.set_index("id")
    gap_end = 30.0 - 5.0 * (N_FRAMES - 1) * DT  # 20.2 m
    assert meta.loc[1, "minDHW"] == pytest.approx(gap_end)
    assert meta.loc[1, "minTHW"] == pytest.approx(gap_end / 30.0)
    assert meta.loc[1, "minTTC"] == pytest.approx(gap_end / 5.0)
    # no preceding vehicle: all three -1
    for vid in (2, 3, 5):
        assert tuple(meta.loc[vid, ["minDHW", "minTHW", "minTTC"]]) == (-1.0, -1.0, -1.0)
    # a leader that is not being closed in on: DHW and THW defined, TTC has no valid value
    assert meta.loc[4, "minDHW"] == pytest.approx(217.0 - 204.5)
    assert meta.loc[4, "minTHW"] == pytest.approx(12.5 / 24.0)
    assert meta.loc[4, "minTTC"] == -1.0


def test_vehicle_criticality_drac() -> None:
    crit = vehicle_criticality(_pair_recording()).set_index("id")
    gap_end = 30.0 - 5.0 * (N_FRAMES - 1) * DT
    assert crit.loc[1, "maxDRAC"] == pytest.approx(5.0**2 / (2.0 * gap_end))
    assert (crit.drop(1)["maxDRAC"] == 0.0).all()


def test_profile_shares_and_flow() -> None:
    rec = _pair_recording()
    p = criticality_profile([rec])
    assert p.n_vehicles == 5 and p.truck_share == pytest.approx(0.2)
    # minTTC 4.04 s: above both thresholds; minTHW 0.52 s (car 4) and 0.673 s (car 1)
    assert p.min_ttc_s.share_below == {"1.5": 0.0, "3": 0.0}
    assert p.min_ttc_s.n_defined == 1 and p.min_ttc_s.median == pytest.approx(4.04)
    assert p.min_thw_s.share_below["0.5"] == 0.0
    assert p.min_thw_s.share_below["1"] == pytest.approx(2 / 5)
    assert p.min_dhw_m.n_defined == 2 and p.min_dhw_m.share_below["10"] == 0.0
    assert p.contact_pairs == 0 and p.drac_above_3_share == 0.0
    table = profile_table({"a": p, "b": p})
    assert "| minTTC < 3 s (share of vehicles) | 0.00 % | 0.00 % |" in table


def test_flow_counts_section_crossings() -> None:
    # Two cars in lane 7 pass x = 100 (the middle of the box range [0, 200]) during 1.96 s.
    states = pd.concat([_track(1, 4.0, 60.0, 30.0, 29.25), _track(2, 4.0, 80.0, 30.0, 29.25),
                        _track(3, 4.0, 0.0, 1.0, 25.75), _track(4, 4.0, 196.0 - 1.96, 1.0, 25.75)],
                       ignore_index=True)
    vehicles = pd.DataFrame({"id": [1, 2, 3, 4], "class": "Car", "drivingDirection": 2})
    rec = build_recording(states, vehicles, recording_id=1, upper_markings_y_m=UPPER, lower_markings_y_m=LOWER)
    p = criticality_profile([rec])
    hours = N_FRAMES * DT / 3600.0
    assert p.flow_veh_per_h_by_lane == {7: pytest.approx(2 / hours)}


def test_overlapping_boxes_hand_made() -> None:
    boxes = pd.DataFrame({
        "frame": [1, 1, 1, 2, 2, 2],
        "id": [1, 2, 3, 1, 2, 3],
        "x": [0.0, 4.0, 4.5, 0.0, 4.5, 20.0],
        "y": [0.0, 1.0, 5.0, 0.0, 0.0, 0.0],
        "width": [4.5, 4.5, 4.5, 4.5, 4.5, 4.5],
        "height": [1.8, 1.8, 1.8, 1.8, 1.8, 1.8],
    })
    out = overlapping_boxes(boxes)
    # frame 1: 1-2 overlap 0.5 m x 0.8 m; 3 is 5 m to the side. Frame 2: 1 and 2 only touch.
    assert out[["frame", "id_a", "id_b"]].to_numpy().tolist() == [[1, 1, 2]]
    assert out.loc[0, "overlap_x_m"] == pytest.approx(0.5) and out.loc[0, "overlap_y_m"] == pytest.approx(0.8)


def test_overlapping_boxes_matches_brute_force() -> None:
    rng = np.random.default_rng(0)
    n = 400
    boxes = pd.DataFrame({"frame": rng.integers(1, 6, n), "id": np.arange(1, n + 1),
                          "x": rng.uniform(0, 200, n), "y": rng.uniform(0, 30, n),
                          "width": rng.uniform(3, 18, n), "height": rng.uniform(1.5, 2.6, n)})
    got = {tuple(r) for r in overlapping_boxes(boxes)[["frame", "id_a", "id_b"]].to_numpy().tolist()}
    want = set()
    for f, g in boxes.groupby("frame"):
        a = g.to_dict("records")
        for i in range(len(a)):
            for j in range(i + 1, len(a)):
                p, q = a[i], a[j]
                if (min(p["x"] + p["width"], q["x"] + q["width"]) > max(p["x"], q["x"])
                        and min(p["y"] + p["height"], q["y"] + q["height"]) > max(p["y"], q["y"])):
                    want.add((f, min(p["id"], q["id"]), max(p["id"], q["id"])))
    assert got == want and len(want) > 10


def _events_frame() -> pd.DataFrame:
    return pd.DataFrame([{"frame": 12, "id": 1, "kind": "hard_brake", "other_id": 2, "lane_id": 7,
                          "target_lane_id": 7, "speed_mps": 30.0, "target_speed_mps": 18.0, "decel_mps2": 6.0,
                          "duration_s": 2.0, "gap_m": 20.0, "reaction_s": 0.6, "held_s": 0.6,
                          "other_decel_mps2": 4.2}], columns=list(EVENTS_COLUMNS))


def test_events_file_round_trip_and_profile(tmp_path: Path) -> None:
    rec = _pair_recording()
    write_recording(rec, tmp_path)
    write_events(_events_frame(), tmp_path, 1)
    back = read_events(tmp_path, 1)
    assert back is not None and back.loc[0, "kind"] == "hard_brake" and back.loc[0, "frame"] == 12
    assert read_events(tmp_path, 2) is None
    p = profile_directory(tmp_path)
    assert p.events_by_kind == {"hard_brake": 1}
    assert p.event_vehicle_share == pytest.approx(2 / 5)  # vehicles 1 and 2 of 5
    assert np.isnan(p.low_ttc_event_share)  # nobody below 3 s
    json.dumps(p.to_dict())  # JSON-ready


@pytest.mark.parametrize(("column", "value", "message"), [
    ("kind", "teleport", "column 'kind', line 2: unknown kind 'teleport'"),
    ("frame", "1.5", "column 'frame', line 2: not an integer"),
])
def test_events_file_errors_name_column_and_line(tmp_path: Path, column: str, value: str, message: str) -> None:
    frame = _events_frame().astype({column: object})
    frame.loc[0, column] = value
    frame.to_csv(tmp_path / "01_events.csv", index=False)
    with pytest.raises(ValueError, match=message):
        read_events(tmp_path, 1)
    (tmp_path / "01_events.csv").write_text("frame,id\n1,2\n")
    with pytest.raises(ValueError, match=r"01_events.csv: missing column"):
        read_events(tmp_path, 1)
