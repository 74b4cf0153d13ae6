"""History risk features (``letspi.scenario.risk_features``): hand-computed values on synthetic scenes."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from letspi.constants import DT_S, T0_INDEX
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.risk_features import FAR_M, RISK_FEATURE_NAMES, THW_CAP_S, risk_features


def _features(**kw: object) -> dict[str, float]:
    batch = straight_road_scenario(**kw).history()  # type: ignore[arg-type]
    return dict(zip(RISK_FEATURE_NAMES, risk_features(batch)[0].tolist(), strict=True))


def test_leader_second_follower_and_side_gaps() -> None:
    f = _features(ego_speed_mps=30.0, neighbours=[
        VehicleSpec(24.5, 25.0, accel_mps2=-2.0), VehicleSpec(54.5, 20.0), VehicleSpec(-14.5, 33.0),
        VehicleSpec(10.5, 30.0, lane_offset=1), VehicleSpec(-20.5, 30.0, lane_offset=-1)])
    assert f["ego_speed_mps"] == pytest.approx(30.0)
    assert f["leader_gap_m"] == pytest.approx(20.0)  # 24.5 m centre offset minus two half lengths
    assert f["leader_closing_mps"] == pytest.approx(5.0)
    assert f["leader_ax_mps2"] == pytest.approx(-2.0, abs=1e-4)
    assert f["leader_thw_s"] == pytest.approx(20.0 / 30.0)
    assert f["leader_inv_ttc_1ps"] == pytest.approx(5.0 / 20.0)
    assert f["second_gap_m"] == pytest.approx(54.5 - 24.5 - 4.5)
    assert f["second_closing_mps"] == pytest.approx(5.0)
    assert f["follower_gap_m"] == pytest.approx(10.0)
    assert f["follower_closing_mps"] == pytest.approx(3.0)
    assert f["left_ahead_gap_m"] == pytest.approx(6.0) and f["left_behind_gap_m"] == FAR_M
    assert f["right_behind_gap_m"] == pytest.approx(16.0) and f["right_ahead_gap_m"] == FAR_M
    assert f["n_vehicles"] == 5


def test_an_empty_road_reads_as_nobody_there_and_missing_lanes_as_no_room() -> None:
    f = _features(ego_speed_mps=25.0, n_lanes=2, ego_lane_index=0)
    assert f["leader_gap_m"] == FAR_M and f["leader_closing_mps"] == 0.0 and f["leader_thw_s"] == THW_CAP_S
    assert f["follower_gap_m"] == FAR_M and f["n_vehicles"] == 0
    assert f["left_ahead_gap_m"] == FAR_M  # a free left lane
    assert f["right_ahead_gap_m"] == 0.0 and f["right_behind_gap_m"] == 0.0  # no right lane


def test_a_car_drifting_towards_the_ego_lane_is_seen() -> None:
    batch = straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(15.0, 30.0, lane_offset=1)])
    t = (np.arange(batch.nbr_xy_m.shape[2]) - T0_INDEX) * DT_S
    xy, vxy = batch.nbr_xy_m.copy(), batch.nbr_vxy_mps.copy()
    xy[0, 0, :, 1] -= (0.6 * t).astype(xy.dtype)
    vxy[0, 0, :, 1] = -0.6
    f = dict(zip(RISK_FEATURE_NAMES, risk_features(replace(batch, nbr_xy_m=xy, nbr_vxy_mps=vxy).history())[0],
                 strict=True))
    assert f["adjacent_towards_mps"] == pytest.approx(0.6, abs=1e-5)
    assert f["adjacent_towards_dx_m"] == pytest.approx(15.0)
