"""Lane and neighbour queries and matching features on hand-built scenarios with known answers."""

import numpy as np
import pytest

from letspi.constants import T0_INDEX
from letspi.scenario.build import LANE_WIDTH_M, VehicleSpec, straight_road_scenario
from letspi.scenario.features import FEATURE_NAMES, scenario_features
from letspi.scenario.queries import OFF_ROAD, lane_id_of, lane_index_of, neighbour_at
from letspi.scenario.types import concat_batches


def _busy():
    return straight_road_scenario(
        ego_speed_mps=30.0,
        n_lanes=3,
        ego_lane_index=1,
        neighbours=[
            VehicleSpec(x0_m=40.0, speed_mps=25.0),  # slot 0: preceding, far
            VehicleSpec(x0_m=20.0, speed_mps=25.0),  # slot 1: preceding, near
            VehicleSpec(x0_m=-15.0, speed_mps=30.0),  # slot 2: following
            VehicleSpec(x0_m=3.0, speed_mps=30.0, lane_offset=1),  # slot 3: left, alongside
            VehicleSpec(x0_m=-30.0, speed_mps=30.0, lane_offset=1),  # slot 4: left, far behind
            VehicleSpec(x0_m=10.0, speed_mps=20.0, lane_offset=-1),  # slot 5: right
        ],
    )


def test_lane_index_and_id_of_points():
    b = _busy()
    y = np.array([[0.0, LANE_WIDTH_M, -LANE_WIDTH_M, 2 * LANE_WIDTH_M, -0.49 * LANE_WIDTH_M]])
    assert lane_index_of(b.marking_y_m, y).tolist() == [[1, 2, 0, OFF_ROAD, 1]]
    # 3+3 road, lower carriageway: lanes 6 (left, next to the median) .. 8 (right)
    assert lane_id_of(b, y).tolist() == [[7, 6, 8, 0, 7]]


def test_lane_index_ignores_nan_padding():
    narrow = straight_road_scenario(n_lanes=2, ego_lane_index=0)
    wide = straight_road_scenario(n_lanes=3, ego_lane_index=0)
    both = concat_batches([narrow, wide])
    assert np.isnan(both.marking_y_m[0, -1])
    y = np.array([[2 * LANE_WIDTH_M], [2 * LANE_WIDTH_M]])
    assert lane_index_of(both.marking_y_m, y)[:, 0].tolist() == [OFF_ROAD, 2]


@pytest.mark.parametrize(
    ("relation", "slot"), [("preceding", 1), ("following", 2), ("left", 3), ("right", 5)]
)
def test_neighbour_relations_at_t0(relation, slot):
    assert neighbour_at(_busy(), T0_INDEX, relation).tolist() == [slot]


def test_neighbour_relation_missing_gives_minus_one():
    b = straight_road_scenario(n_lanes=2, ego_lane_index=0, neighbours=[VehicleSpec(20.0, 30.0)])
    assert neighbour_at(b, T0_INDEX, "right").tolist() == [-1]
    assert neighbour_at(b, T0_INDEX, "following").tolist() == [-1]
    with pytest.raises(ValueError, match="relation must be one of"):
        neighbour_at(b, T0_INDEX, "above")  # type: ignore[arg-type]


def test_features_known_values():
    f = scenario_features(_busy())[0]
    named = dict(zip(FEATURE_NAMES, f, strict=True))
    assert named["n_vehicles"] == 6
    assert named["ego_speed_mps"] == pytest.approx(30.0)
    assert named["lane_change"] == 0.0
    expected_d = [40.0, 20.0, 15.0, np.hypot(3.0, LANE_WIDTH_M), np.hypot(30.0, LANE_WIDTH_M),
                  np.hypot(10.0, LANE_WIDTH_M)]
    assert named["min_dist_m"] == pytest.approx(min(expected_d), rel=1e-5)
    assert named["mean_dist_m"] == pytest.approx(np.mean(expected_d), rel=1e-5)
    assert named["mean_nbr_speed_mps"] == pytest.approx(np.mean([25, 25, 30, 30, 30, 20]))


def test_features_without_neighbours_and_hidden_ones():
    hidden = VehicleSpec(x0_m=10.0, speed_mps=30.0, visible_from_index=T0_INDEX + 5)
    b = straight_road_scenario(ego_speed_mps=20.0, neighbours=[hidden])
    f = scenario_features(b)[0]
    assert f.tolist() == [0.0, 20.0, 0.0, 100.0, 100.0, 20.0]
