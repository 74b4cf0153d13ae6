"""Scene features of the learned models, the by-vehicle split, and the random scenes other
``test_learned_*`` modules import (``random_batch``)."""

from __future__ import annotations

import numpy as np

from letspi.learned.features import N_HIST_STEPS, N_LANE_FEATURES, N_STATIC_FEATURES, N_STEP_FEATURES, scene_features
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.split import split_by_key, split_by_recording, split_by_vehicle
from letspi.scenario.types import ScenarioBatch, concat_batches


def random_batch(rng: np.random.Generator, n: int) -> ScenarioBatch:
    """Hand-built straight-road scenes with random dense traffic (close leaders, lane neighbours)."""
    scenes = []
    for i in range(n):
        n_lanes = int(rng.integers(2, 5))
        ego_lane = int(rng.integers(0, n_lanes))
        specs = []
        for _ in range(int(rng.integers(0, 9))):
            off = int(rng.integers(-ego_lane, n_lanes - ego_lane))
            specs.append(VehicleSpec(x0_m=float(rng.uniform(-60, 80)), speed_mps=float(rng.uniform(10, 40)),
                                     lane_offset=off, accel_mps2=float(rng.uniform(-3, 1)),
                                     y_offset_m=float(rng.uniform(-1.0, 1.0)), length_m=float(rng.uniform(4, 16))))
        sc = straight_road_scenario(ego_speed_mps=float(rng.uniform(15, 38)), ego_accel_mps2=float(rng.uniform(-2, 1)),
                                    neighbours=specs, n_lanes=n_lanes, ego_lane_index=ego_lane,
                                    scenario_id=f"rand{i}")
        scenes.append(sc)
    return concat_batches(scenes)


def test_features_shapes_masks_and_no_future() -> None:
    batch = random_batch(np.random.default_rng(0), 12)
    f = scene_features(batch)
    b, a = len(batch), 1 + batch.n_neighbours
    assert f.agent_hist.shape == (b, a, N_HIST_STEPS, N_STEP_FEATURES)
    assert f.agent_static.shape == (b, a, N_STATIC_FEATURES)
    assert f.lane.shape == (b, N_LANE_FEATURES)
    assert f.anchor_xy.shape == (b, 2)
    for arr in (f.agent_hist, f.agent_static, f.lane, f.anchor_xy):
        assert np.isfinite(arr).all()
    assert f.agent_mask[:, 0].all()
    np.testing.assert_array_equal(f.agent_mask[:, 1:], batch.nbr_valid[:, :, 74])
    assert (f.agent_hist[~f.agent_mask] == 0).all()
    # changing the future changes nothing
    fut = batch.ego_xy_m.copy()
    fut[:, 75:] += 100.0
    nfut = batch.nbr_xy_m.copy()
    nfut[:, :, 75:] = -50.0
    from dataclasses import replace

    g = scene_features(replace(batch, ego_xy_m=fut, nbr_xy_m=nfut))
    np.testing.assert_array_equal(g.agent_hist, f.agent_hist)
    np.testing.assert_array_equal(g.lane, f.lane)


def test_split_by_vehicle_has_no_leakage() -> None:
    rng = np.random.default_rng(1)
    batch = random_batch(rng, 60)
    # several windows per vehicle; two "files" whose recordings share id 1 but not their content key
    ego = rng.integers(1, 15, size=len(batch)).astype(np.int32)
    key = np.where(np.arange(len(batch)) < 30, "recA", "recB").astype(object)
    from dataclasses import replace

    batch = replace(batch, ego_id=ego, recording_id=np.ones(len(batch), np.int32), recording_key=key)
    train, val = split_by_vehicle(batch, 0.7, seed=3)
    assert len(train) and len(val) and len(train) + len(val) == len(batch)
    keys = [set(zip(batch.recording_key[i], batch.ego_id[i], strict=True)) for i in (train, val)]
    assert not keys[0] & keys[1]
    # vehicle 5 of file A and vehicle 5 of file B are different vehicles: both sides may hold one
    by_rec = split_by_recording(batch, 0.5, seed=0)
    assert {str(k) for k in batch.recording_key[by_rec[0]]} != {str(k) for k in batch.recording_key[by_rec[1]]}


def test_split_by_key_keeps_groups_whole_and_splits_by_group_count() -> None:
    keys = np.array(["a"] * 7 + ["b"] * 1 + ["c"] * 2 + ["d"] * 5, dtype=object)
    train, val = split_by_key(keys, 0.5, seed=0)
    assert sorted([*train, *val]) == list(range(len(keys)))
    assert not set(keys[train]) & set(keys[val])
    assert len(set(keys[train])) == 2 and len(set(keys[val])) == 2  # half of the 4 groups, whatever their sizes
    again = split_by_key(keys, 0.5, seed=0)
    np.testing.assert_array_equal(again[0], train)
