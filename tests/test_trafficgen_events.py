"""Scripted events, presets, layouts and the no-contact policy of the SUMO generator (real SUMO)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from letspi.highd.contacts import overlapping_boxes
from letspi.highd.criticality import profile_directory
from letspi.highd.events import read_events
from letspi.highd.io import read_recording
from letspi.highd.types import Recording
from letspi.trafficgen.config import traffic_preset, with_overrides

pytestmark = pytest.mark.sumo
DT_S = 0.04


def _generate(out: Path, preset: str = "highd", minutes: float = 1.5, seed: int = 3, **settings: str):  # type: ignore[no-untyped-def]
    pytest.importorskip("sumo")
    from letspi.trafficgen.generate import generate_highd

    cfg = with_overrides(traffic_preset(preset), {k.replace("__", "."): v for k, v in settings.items()})
    return generate_highd(out, minutes=minutes, seed=seed, traffic=cfg)


def _travel_sign(rec: Recording, vid: int) -> float:
    """+1 for direction 2 (towards +x), -1 for direction 1: image-axis values times it point forward."""
    return 1.0 if int(rec.tracks_meta.set_index("id").loc[vid, "drivingDirection"]) == 2 else -1.0


@pytest.fixture(scope="module")
def braking(tmp_path_factory: pytest.TempPathFactory) -> tuple[Recording, pd.DataFrame]:
    out = tmp_path_factory.mktemp("hard_brake")
    _generate(out, events__hard_brake_per_min="6", events__cut_in_per_min="0", events__truck_pullout_per_min="0",
              drivers__lane_change_perception="false")
    events = read_events(out, 1)
    assert events is not None
    return read_recording(out, 1), events


def test_hard_brake_appears_at_the_stated_frame_with_the_stated_deceleration(braking) -> None:  # type: ignore[no-untyped-def]
    rec, events = braking
    assert set(events["kind"]) == {"hard_brake"} and len(events) >= 2
    tracks = rec.tracks.set_index(["id", "frame"])
    for e in events.itertuples():
        sign = _travel_sign(rec, e.id)
        actor = tracks.loc[e.id]
        accel = sign * actor["xAcceleration"]  # along the travel direction
        speed = sign * actor["xVelocity"]
        n = round(e.duration_s / DT_S)  # braking steps: frames e.frame .. e.frame + n - 1
        # Accelerations are central differences of central-difference velocities, which spread a
        # jump over the neighbouring frames: two frames before the stated one the vehicle is not
        # braking; from the stated frame to two frames before its last braking step the recorded
        # deceleration is exactly the stated one.
        assert accel.loc[e.frame - 2] > -0.3 * e.decel_mps2, e
        braking_accel = accel.loc[e.frame:e.frame + n - 3].to_numpy()
        assert len(braking_accel) == n - 2
        np.testing.assert_allclose(braking_accel, -e.decel_mps2, atol=0.05)
        assert 4.0 <= e.decel_mps2 <= 8.0 and 1.5 - DT_S <= e.duration_s <= 3.0 + DT_S
        # from the stated speed to the stated lower speed
        assert speed.loc[e.frame - 2] == pytest.approx(e.speed_mps, abs=0.1)
        assert speed.loc[e.frame + n] == pytest.approx(e.target_speed_mps, abs=0.1)
        assert e.target_speed_mps == pytest.approx(e.speed_mps - e.decel_mps2 * e.duration_s, abs=1e-5)


def test_hard_brake_follower_reacts_after_its_reaction_time(braking) -> None:  # type: ignore[no-untyped-def]
    rec, events = braking
    tracks = rec.tracks.set_index(["id", "frame"])
    for e in events.itertuples():
        assert tracks.loc[(e.other_id, e.frame), "precedingId"] == e.id
        assert 0.2 <= e.reaction_s <= 1.0 and 0.0 < e.held_s <= e.reaction_s + 1e-9
        follower = _travel_sign(rec, e.other_id) * tracks.loc[e.other_id, "xAcceleration"]
        held_frames = round(e.held_s / DT_S)
        if held_frames >= 6:  # the follower keeps its speed while it has not reacted yet
            assert np.abs(follower.loc[e.frame + 2:e.frame + held_frames - 3]).max() < 0.1
        # ... and then brakes (at most SUMO's emergency deceleration)
        after = follower.loc[e.frame + held_frames:e.frame + held_frames + 50]
        assert after.min() < -1.0 and after.min() >= -9.0 - 0.2


def test_cut_in_changes_lane_in_front_of_a_faster_follower(tmp_path: Path) -> None:
    _generate(tmp_path, events__hard_brake_per_min="0", events__cut_in_per_min="6", events__truck_pullout_per_min="0",
              seed=5)
    rec = read_recording(tmp_path, 1)
    events = read_events(tmp_path, 1)
    assert events is not None and len(events) >= 2 and set(events["kind"]) == {"cut_in"}
    tracks = rec.tracks.set_index(["id", "frame"])
    for e in events.itertuples():
        assert e.target_lane_id != e.lane_id and abs(e.target_lane_id - e.lane_id) == 1
        assert tracks.loc[(e.id, e.frame), "laneId"] == e.lane_id
        last = int(rec.tracks_meta.set_index("id").loc[e.id, "finalFrame"])
        if e.frame + 75 <= last:  # the centre crosses after 2 s, the change ends after 4 s
            assert tracks.loc[(e.id, e.frame + 75), "laneId"] == e.target_lane_id
        # the follower was faster than the cutting car at the start
        v_actor = abs(tracks.loc[(e.id, e.frame), "xVelocity"])
        v_foll = abs(tracks.loc[(e.other_id, e.frame), "xVelocity"])
        assert v_foll - v_actor >= 2.0 - 0.1
    profile = profile_directory(tmp_path)
    assert profile.min_ttc_s.share_below["3"] > 0.0 and profile.contact_pairs == 0


@pytest.mark.slow
def test_presets_differ_measurably(tmp_path: Path) -> None:
    profiles = {}
    for preset in ("calm", "stress"):
        report = _generate(tmp_path / preset, preset=preset, minutes=3.0, seed=0)
        assert report.attempt == 0 or report.rejected
        profiles[preset] = profile_directory(tmp_path / preset)
    calm, stress = profiles["calm"], profiles["stress"]
    assert calm.events_by_kind == {} and sum(stress.events_by_kind.values()) >= 10
    assert calm.min_ttc_s.share_below["3"] == 0.0
    assert stress.min_ttc_s.share_below["3"] >= 0.03
    assert stress.drac_above_3_share > calm.drac_above_3_share
    assert calm.contact_pairs == 0 and stress.contact_pairs == 0


@pytest.mark.parametrize("layout", ["on_ramp", "lane_drop"])
@pytest.mark.slow  # over ~10 s on a loaded 2-core machine (notes/reliability.md)
def test_layouts_record_the_main_carriageway_only(tmp_path: Path, layout: str) -> None:
    _generate(tmp_path, minutes=1.5, seed=2, layout__kind=layout, events__hard_brake_per_min="0",
              events__cut_in_per_min="8", events__truck_pullout_per_min="0")
    rec = read_recording(tmp_path, 1)
    events = read_events(tmp_path, 1)
    assert events is not None and (events["kind"] == "cut_in").sum() >= 1  # lane indices mapped on every edge
    tr = rec.tracks
    assert len(rec.upper_markings_y_m) == 4 and len(rec.lower_markings_y_m) == 4  # 3 main lanes each
    assert set(tr["laneId"].unique()) <= {2, 3, 4, 6, 7, 8}
    assert overlapping_boxes(tr).empty
    # Vehicles from the ramp / the ending lane enter the recording mid-window, in the right lane,
    # when their centre crosses onto the main carriageway.
    first = tr.sort_values("frame").groupby("id").first()
    centre_x = first["x"] + first["width"] / 2
    mid_window = (centre_x > 60.0) & (centre_x < 360.0) & (first.index.map(
        rec.tracks_meta.set_index("id")["initialFrame"]) > 1)
    right_lane = np.where(first.index.map(rec.tracks_meta.set_index("id")["drivingDirection"]) == 2, 8, 2)
    merged = mid_window & (first["laneId"].to_numpy() == right_lane)
    assert merged.sum() >= 2, first[mid_window]


def test_contact_is_never_written(tmp_path: Path) -> None:
    """Followers released only beyond SUMO's emergency deceleration crash; the run must fail loudly."""
    with pytest.raises(RuntimeError, match=r"seed 4: every one of 1 simulation attempts had contact"):
        _generate(tmp_path, minutes=1.5, seed=4, events__hard_brake_per_min="10", events__cut_in_per_min="0",
                  events__truck_pullout_per_min="0", events__release_decel_mps2="15", events__release_gap_m="1",
                  events__follower_brake_ratio="0.1,0.1", drivers__reaction_time_s="1.0,1.0",
                  events__hard_brake_decel_mps2="8,8", max_attempts="1")
    assert not any(tmp_path.glob("*_tracks.csv"))
