"""The decision step's option checks (``letspi.method.decide``) and the cached option outcomes
(``letspi.finetune.options``) on synthetic scenes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from letspi.finetune.options import OptionRun, load_option_run, random_option_table, score_options
from letspi.method.decide import (
    OptionTable,
    check_options,
    defaults_vector,
    load_presets,
    plan_options,
    with_defaults,
)
from letspi.metrics.compute import compute_outcomes
from letspi.physics.goals import KinematicGoalPredictor
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.params import SocialForceParams
from letspi.physics.types import NeighbourPrediction
from letspi.safety.adverse import adverse_futures, check_futures
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import concat_batches

PARAMS = SocialForceParams(tau_s=2.0, k_np=21.0, k_nf=9.0, k_nl=0.2, k_boundary=0.5, k_cline=0.5, r_col_m=5.0)


def _table() -> OptionTable:
    d = defaults_vector(PARAMS)
    slow, left = d.copy(), d.copy()
    slow[6] = 1.0  # goal 30 % shorter
    left[7] = -1.0
    return OptionTable(("default", "slow", "lane-left"), np.stack([d, slow, left]))


def _scenes():  # type: ignore[no-untyped-def]
    return concat_batches([
        straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(22.0, 30.0)], scenario_id="leader"),
        straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(-40.0, 30.0, lane_offset=1)],
                               scenario_id="free"),
    ])


def test_check_options_agrees_with_checking_each_plan_by_hand() -> None:
    batch = _scenes()
    hist = batch.history()
    goals = KinematicGoalPredictor().predict_goals(hist).top
    pred = predict_neighbours(hist, NeighbourPredictionMode.IDM)
    table = _table()
    chk = check_options(hist, goals, pred, table, 5.0)
    assert chk.names == table.names and chk.adverse_names == ("leader-brakes", "cut-in", "follower-keeps")
    xy, vxy, _ = plan_options(hist, table.values, goals, pred, 5.0)
    np.testing.assert_array_equal(chk.xy_m.reshape(-1, *xy.shape[1:]), xy)
    np.testing.assert_allclose(chk.progress_m, xy[:, -1, 0].reshape(2, 3))
    # scene 0 by hand: the default plan follows the leader and hits it when it brakes hard
    pred_take = NeighbourPrediction(*(np.asarray(a)[:1] for a in pred))
    fut = adverse_futures(hist.take([0]), pred_take)
    by_hand = check_futures(hist.take([0]), xy[:1], vxy[:1], pred_take, fut)
    assert chk.adverse_failed[0, 0, 0] == by_hand.collision[0, 1]
    assert chk.failed_names(0, 0) == ["leader-brakes"]
    assert not chk.adverse_failed[1].any()  # nobody ahead, nobody drifting, the follower is far
    assert chk.passes_all()[1].all() and chk.failed_checks()[0, 0] >= 1


def test_score_options_pairs_hindsight_and_checks_and_the_run_resumes(tmp_path: Path) -> None:
    batch = _scenes()
    table = _table()
    gp = KinematicGoalPredictor()
    scored = score_options(batch, table, gp, PARAMS, checks=True)
    hist = batch.history()
    goals = gp.predict_goals(hist).top
    pred = predict_neighbours(hist, NeighbourPredictionMode.IDM)
    xy, vxy, _ = plan_options(hist, table.values, goals, pred, 5.0)
    out = compute_outcomes(batch.take(np.repeat(np.arange(2), 3)), xy, vxy)
    np.testing.assert_array_equal(scored.collision, out.collision.reshape(2, 3))
    np.testing.assert_array_equal(scored.adverse_failed, check_options(hist, goals, pred, table, 5.0).adverse_failed)
    with pytest.raises(ValueError, match="recorded future"):
        score_options(hist, table, gp, PARAMS)
    run = OptionRun.create(batch, table, tmp_path / "o", gp, PARAMS, goals="kinematic", checks=True, chunk=1)
    first = run.run()
    np.testing.assert_array_equal(first.adverse_failed, scored.adverse_failed)
    (tmp_path / "o" / "parts" / "part-000001.npz").unlink()  # as if killed after the first chunk
    again = run.run()
    np.testing.assert_array_equal(again.collision, first.collision)
    t, o, manifest = load_option_run(tmp_path / "o")
    assert t.names == table.names and manifest["n_windows"] == 2 and len(o) == 2
    other = OptionRun.create(batch, random_option_table(PARAMS, 4, 0), tmp_path / "o", gp, PARAMS, goals="kinematic")
    with pytest.raises(ValueError, match="other settings"):
        other.run()


def test_presets_file_and_own_defaults(tmp_path: Path) -> None:
    table = _table()
    path = tmp_path / "p.json"
    path.write_text(json.dumps({"format": "letspi-presets/1", **table.to_json()}))
    loaded, record = load_presets(path)
    assert loaded.names == table.names and record["format"] == "letspi-presets/1"
    other = SocialForceParams(tau_s=1.5, k_np=30.0, k_nf=9.0, k_nl=0.2, k_boundary=0.5, k_cline=0.5, r_col_m=5.0)
    mine = with_defaults(loaded, other)
    np.testing.assert_array_equal(mine.values[0], defaults_vector(other))
    np.testing.assert_array_equal(mine.values[1:], table.values[1:])
    path.write_text(json.dumps({"format": "letspi-presets/1", "names": ["slow"], "values": [table.values[1].tolist()]}))
    with pytest.raises(ValueError, match="first preset must be 'default'"):
        load_presets(path)
