"""Physics-verified labels (``letspi train llm-data``): ranges, safety of the label, determinism, refine rows."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from letspi.cli.app import app
from letspi.llm.schema import FIELD_RANGES, NUMERIC_FIELDS
from letspi.method.reflection import simulate_proposal
from letspi.physics.goals import KinematicGoalPredictor
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.params import SocialForceParams
from letspi.safety.plan_check import check_recorded
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.store import save_scenarios
from letspi.scenario.types import ScenarioBatch, concat_batches

pytest.importorskip("letspi_train", reason="letspi-train is not installed (pip install -e packages/letspi-train)")
from letspi_train.finetune.labels import (
    LABEL_COLUMNS,
    PROPOSAL_COLUMNS,
    LabelRun,
    LabelSearch,
    defaults_vector,
    label_rows,
    load_labels,
    params_of,
)

WEAK = SocialForceParams(k_np=2.0, k_nf=3.0, tau_s=1.0, r_col_m=5.0)  # drives into a slower leader
SMALL = LabelSearch(n_random=16, n_rounds=1, n_local=8, chunk=4)


def _batch() -> ScenarioBatch:
    return concat_batches([
        straight_road_scenario(ego_speed_mps=33.0, neighbours=[VehicleSpec(x0_m=40.0, speed_mps=20.0)],
                               scenario_id="leader"),
        straight_road_scenario(ego_speed_mps=28.0, neighbours=[VehicleSpec(x0_m=-30.0, speed_mps=30.0)],
                               scenario_id="follower"),
        straight_road_scenario(ego_speed_mps=30.0, scenario_id="free"),
    ])


def _plan_of(batch: ScenarioBatch, values: np.ndarray, r_col_m: float) -> tuple[np.ndarray, np.ndarray]:
    hist = batch.history()
    goals = KinematicGoalPredictor().predict_goals(hist).top
    plan = simulate_proposal(batch, params_of(values, r_col_m), values[:, 6], values[:, 7], goals,
                             predict_neighbours(hist, NeighbourPredictionMode.IDM))
    return plan.xy_m, plan.vxy_mps


def _rows(batch: ScenarioBatch, seed: int = 0, params: SocialForceParams = WEAK) -> pd.DataFrame:
    return pd.DataFrame(label_rows(batch, np.arange(len(batch)), KinematicGoalPredictor(), params, SMALL, seed))


def test_labels_are_in_range_safe_and_a_colliding_default_gets_a_safe_label() -> None:
    batch = _batch()
    # the fitted defaults (here: weak) crash into the leader of scenario 0 in the recorded future
    default_xy, default_vxy = _plan_of(batch.take([0]), defaults_vector(WEAK)[None], WEAK.r_col_m)
    assert check_recorded(batch.take([0]), default_xy, default_vxy).collision[0]

    df = _rows(batch)
    assert list(df.columns) == list(LABEL_COLUMNS)
    for f in NUMERIC_FIELDS:
        lo, hi = FIELD_RANGES[f]
        assert df[f].between(lo, hi).all(), f
    propose = df[df.kind == "propose"].set_index("scenario_index")
    assert len(propose) == 3 and propose["label_safe"].all()
    values = propose[list(NUMERIC_FIELDS)].to_numpy()
    xy, vxy = _plan_of(batch, values, WEAK.r_col_m)
    check = check_recorded(batch, xy, vxy)  # the label passes the checks against the recorded future
    assert (check.safe(SMALL.ttc_s, SMALL.min_dist_m)).all()
    assert propose.loc[0, "k_np"] > WEAK.k_np  # it had to repel harder than the defaults


def test_refine_rows_pair_a_rejected_proposal_and_its_report_with_a_safe_label() -> None:
    df = _rows(_batch())
    refine = df[df.kind == "refine"]
    assert len(refine) >= 1 and (df[df.kind == "propose"][list(PROPOSAL_COLUMNS)].isna().all().all())
    for _, row in refine.iterrows():
        proposal = row[list(PROPOSAL_COLUMNS)].to_numpy(dtype=float)
        assert np.isfinite(proposal).all() and row["label_safe"]
        report = json.loads(row["report_json"])
        assert report["failed"] and "UNSAFE" in report["text"]
        assert not np.allclose(proposal, row[list(NUMERIC_FIELDS)].to_numpy(dtype=float))
    # scenario 0's rejected defaults are the weak fitted parameters, and their report names the contact
    first = refine[refine.scenario_index == 0].iloc[0]
    np.testing.assert_allclose(first[list(PROPOSAL_COLUMNS)].to_numpy(dtype=float), defaults_vector(WEAK))
    assert json.loads(first["report_json"])["collision"]


def test_labels_are_deterministic_per_seed_and_independent_of_chunking() -> None:
    batch = _batch()
    a, b, c = _rows(batch, seed=3), _rows(batch, seed=3), _rows(batch, seed=4)
    pd.testing.assert_frame_equal(a, b)
    one = pd.DataFrame(label_rows(batch.take([2]), np.array([2]), KinematicGoalPredictor(), WEAK, SMALL, 3))
    pd.testing.assert_frame_equal(one.reset_index(drop=True),
                                  a[a.scenario_index == 2].reset_index(drop=True))
    assert not a[list(NUMERIC_FIELDS)].equals(c[list(NUMERIC_FIELDS)])  # another seed, other candidates


def test_label_run_writes_the_directory_format_resumes_and_refuses_other_settings(tmp_path: Path) -> None:
    batch = _batch()
    run = LabelRun(scenarios_path=tmp_path / "s.arrow", batch=batch, out=tmp_path / "labels",
                   goal_predictor=KinematicGoalPredictor(), params=WEAK, search=SMALL, seed=0)
    manifest = run.run()
    df, loaded = load_labels(tmp_path / "labels")
    assert loaded["complete"] and manifest["n_scenarios"] == 3 and manifest["n_propose"] == 3
    assert manifest["n_refine"] == int((df.kind == "refine").sum()) and loaded["format"] == "letspi-llm-labels/1"
    assert {"dataset_digest", "sf_params_sha256", "elapsed_s", "seed", "search", "created"} <= set(loaded)
    parts = sorted((tmp_path / "labels" / "parts").iterdir())
    mtimes = [p.stat().st_mtime_ns for p in parts]
    run.run()  # resumes: nothing recomputed
    assert [p.stat().st_mtime_ns for p in parts] == mtimes
    other = LabelRun(scenarios_path=tmp_path / "s.arrow", batch=batch, out=tmp_path / "labels",
                     goal_predictor=KinematicGoalPredictor(), params=WEAK, search=SMALL, seed=1)
    with pytest.raises(ValueError, match="other settings"):
        other.run()


def test_cli_llm_data(tmp_path: Path) -> None:
    path = save_scenarios(_batch(), tmp_path / "s.arrow")
    out = tmp_path / "labels"
    result = CliRunner().invoke(app, ["train", "llm-data", "--scenarios", str(path), "--out", str(out),
                                      "--n-random", "8", "--n-rounds", "1", "--n-local", "4", "--goals", "kinematic"])
    assert result.exit_code == 0, result.output
    df, manifest = load_labels(out)
    assert len(df) == manifest["n_propose"] + manifest["n_refine"]
    assert manifest["n_propose"] == 3 and "scenarios/s" in result.output
    bad = CliRunner().invoke(app, ["train", "llm-data", "--scenarios", str(tmp_path / "none.arrow"), "--out",
                                   str(out)])
    assert bad.exit_code != 0 and "none.arrow" in bad.output
