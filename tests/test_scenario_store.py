"""Parquet round trip and clear errors for scenario files."""

from dataclasses import fields

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.store import ScenarioFileError, count_scenarios, load_scenarios, save_scenarios
from letspi.scenario.types import SCHEMA_VERSION, ScenarioBatch, concat_batches


def _batch() -> ScenarioBatch:
    a = straight_road_scenario(neighbours=[VehicleSpec(20.0, 25.0)], scenario_id="a")
    b = straight_road_scenario(n_lanes=2, ego_lane_index=0, scenario_id="b")
    return concat_batches([a, b])


@pytest.mark.parametrize("name", ["s.arrow", "s.parquet"])
def test_round_trip_is_exact(tmp_path, name):
    batch = _batch()
    path = save_scenarios(batch, tmp_path / name)
    back = load_scenarios(path)
    for f in fields(ScenarioBatch):
        want, got = getattr(batch, f.name), getattr(back, f.name)
        assert got.shape == want.shape, f.name
        if f.name == "scenario_id":
            assert got.tolist() == want.tolist()
        else:
            assert got.dtype == want.dtype, f.name
            np.testing.assert_array_equal(got, want, err_msg=f.name)
    assert count_scenarios(path) == 2


def test_load_subset(tmp_path):
    path = save_scenarios(_batch(), tmp_path / "s.parquet")
    assert load_scenarios(path, [1]).scenario_id.tolist() == ["b"]
    with pytest.raises(ScenarioFileError, match="index out of range"):
        load_scenarios(path, [5])


def test_errors_name_the_file(tmp_path):
    with pytest.raises(ScenarioFileError, match="no such scenario file"):
        load_scenarios(tmp_path / "missing.parquet")
    foreign = tmp_path / "foreign.parquet"
    pq.write_table(pa.table({"x": [1, 2]}), foreign)
    with pytest.raises(ScenarioFileError, match="foreign.parquet: file without letspi metadata"):
        load_scenarios(foreign)
    garbage = tmp_path / "garbage.parquet"
    garbage.write_text("not parquet")
    with pytest.raises(ScenarioFileError, match="garbage.parquet: not a letspi scenario file"):
        load_scenarios(garbage)


def test_schema_version_mismatch(tmp_path, monkeypatch):
    import letspi.scenario.store as store

    path = save_scenarios(_batch(), tmp_path / "s.parquet")
    monkeypatch.setattr(store, "SCHEMA_VERSION", 99)
    expected = f"scenario schema version {SCHEMA_VERSION} found, this letspi reads version 99"
    with pytest.raises(ScenarioFileError, match=expected):
        store.load_scenarios(path)
