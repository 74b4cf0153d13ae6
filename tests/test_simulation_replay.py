"""``closed-loop-log`` without SUMO (``letspi.simulation.replay``): the same trajectories, plans and
metrics as SUMO's lockstep, no SUMO started, no SUMO collision columns, and a key of its own."""

from __future__ import annotations

from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import pytest
from test_simulation_support import BrakePlanner, SwervePlanner, WildPlanner, as_built, generated_batch
from typer.testing import CliRunner

from letspi.cli.app import app
from letspi.constants import N_TOTAL, T0_INDEX
from letspi.evaluation.closed_loop import mode_settings
from letspi.evaluation.results import load_planner_results
from letspi.metrics.compute import human_future
from letspi.scenario.store import save_scenarios
from letspi.scenario.types import ScenarioBatch
from letspi.simulation import ClosedLoopChunk, ClosedLoopConfig, PlannerSpec, chunk_metrics, run_closed_loop
from letspi.simulation.worker import ChunkWorker, make_tasks

pytestmark = pytest.mark.sumo
LOG, REACTIVE, HYBRID = "closed-loop-log", "closed-loop-reactive", "closed-loop-hybrid"
runner = CliRunner()


@pytest.fixture(scope="module")
def traffic(tmp_path_factory: pytest.TempPathFactory) -> ScenarioBatch:
    """Critical traffic (conflicts, lane changes, vehicles entering and leaving), both directions."""
    return generated_batch(tmp_path_factory.mktemp("replay_traffic"), n=40, criticality="stress")


def _run(planner: object, batch: ScenarioBatch, simulator: str, replan_s: float = 0.2) -> ClosedLoopChunk:
    config = ClosedLoopConfig(LOG, replan_s=replan_s, simulator=simulator, chunk_size=16)  # type: ignore[arg-type]
    chunk = ClosedLoopChunk.concat(list(run_closed_loop(as_built(planner), batch, config)))  # type: ignore[arg-type]
    return chunk.take(np.argsort(chunk.indices))


@pytest.mark.parametrize("planner", [PlannerSpec.of("sf"), PlannerSpec.of("idm"), BrakePlanner(8.0),
                                     SwervePlanner(1.5), WildPlanner()], ids=lambda p: getattr(p, "name", "?"))
def test_the_replay_gives_sumo_s_trajectories_plans_and_metrics(traffic: ScenarioBatch, planner: object) -> None:
    sumo, replay = _run(planner, traffic, "sumo"), _run(planner, traffic, "replay")
    assert sumo.simulator == "sumo" and replay.simulator == "replay"
    np.testing.assert_array_equal(replay.nbr_valid, sumo.nbr_valid)
    np.testing.assert_array_equal(replay.nbr_lane_id, sumo.nbr_lane_id)
    np.testing.assert_array_equal(replay.plan_nonfinite, sumo.plan_nonfinite)
    np.testing.assert_array_equal(replay.replan_step, sumo.replan_step)
    for name in ("ego_xy_m", "ego_vxy_mps", "nbr_xy_m", "nbr_vxy_mps", "plan_xy_m", "plan_goal_xy_m"):
        np.testing.assert_allclose(getattr(replay, name), getattr(sumo, name), atol=1e-6, rtol=0, err_msg=name)
    m_sumo, m_replay = chunk_metrics(traffic, sumo), chunk_metrics(traffic, replay)
    for f in fields(m_sumo):
        got, want = getattr(m_replay, f.name), getattr(m_sumo, f.name)
        pairs = [(f"{f.name}.{k}", got[k], want[k]) for k in want] if isinstance(want, dict) else [(f.name, got, want)]
        assert not isinstance(want, dict) or set(got) == set(want)
        for name, x, y in pairs:
            a, b = np.asarray(x), np.asarray(y)
            if a.dtype.kind not in "fc":
                np.testing.assert_array_equal(a, b, err_msg=name)
            else:
                np.testing.assert_allclose(a, b, atol=1e-6, rtol=1e-9, err_msg=name)
    # the replay runs no SUMO, so it reports no SUMO contact (the metric's collision is the result)
    assert not replay.sumo_contact.any() and replay.sumo_nbr_collisions.sum() == 0
    if isinstance(planner, BrakePlanner):  # the case must be one where collisions happen
        assert m_replay.collision.any() and sumo.sumo_collision.any()
    if isinstance(planner, WildPlanner):
        assert replay.plan_nonfinite[:2].all()


def test_human_replays_the_log_exactly(traffic: ScenarioBatch) -> None:
    ch = _run(PlannerSpec.of("human"), traffic, "replay", replan_s=1.0)
    truth_xy, truth_v = human_future(traffic)
    np.testing.assert_allclose(ch.ego_xy_m, truth_xy, atol=1e-6)
    np.testing.assert_allclose(ch.ego_vxy_mps, truth_v, atol=1e-6)
    fut = slice(T0_INDEX + 1, N_TOTAL)
    np.testing.assert_array_equal(ch.nbr_valid, traffic.nbr_valid[:, :, fut])
    assert np.isnan(ch.nbr_xy_m[~ch.nbr_valid]).all()
    assert not chunk_metrics(traffic, ch).collision.any()


def test_the_replay_starts_no_sumo(traffic: ScenarioBatch) -> None:
    config = ClosedLoopConfig(LOG)  # type: ignore[arg-type]
    worker = ChunkWorker(PlannerSpec.of("cv"), config)
    try:
        chunk = worker.run(make_tasks(traffic.take(np.arange(4)), config)[0])
        assert chunk.simulator == "replay" and len(chunk) == 4
        assert not worker.session._started and worker.session.api is None
    finally:
        worker.close()


def test_which_simulator_runs_and_what_is_refused() -> None:
    assert not ClosedLoopConfig(LOG).uses_sumo  # type: ignore[arg-type]
    assert ClosedLoopConfig(LOG, simulator="sumo").uses_sumo  # type: ignore[arg-type]
    assert ClosedLoopConfig(LOG, sumo_gui=True).uses_sumo  # type: ignore[arg-type]
    assert ClosedLoopConfig(REACTIVE).uses_sumo and ClosedLoopConfig(HYBRID).uses_sumo  # type: ignore[arg-type]
    # a default configuration moved to another mode simulates that mode in SUMO
    assert replace(ClosedLoopConfig(LOG), mode=REACTIVE).uses_sumo  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="closed-loop-log only: closed-loop-reactive needs SUMO"):
        ClosedLoopConfig(REACTIVE, simulator="replay")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="--sumo-gui shows SUMO"):
        ClosedLoopConfig(LOG, simulator="replay", sumo_gui=True)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="simulator must be"):
        ClosedLoopConfig(LOG, simulator="carla")  # type: ignore[arg-type]


def test_chunk_sizes_by_simulator_and_planner(traffic: ScenarioBatch) -> None:
    """The replay's planners get 256 scenarios per chunk, SUMO and the LLM planners 32, unless set; the plans
    do not depend on it (float rounding)."""
    assert ClosedLoopConfig(LOG).scenarios_per_chunk() == 256  # type: ignore[arg-type]
    assert ClosedLoopConfig(LOG).scenarios_per_chunk(dual_rate=True) == 32  # type: ignore[arg-type]
    assert ClosedLoopConfig(LOG, simulator="sumo").scenarios_per_chunk() == 32  # type: ignore[arg-type]
    assert ClosedLoopConfig(REACTIVE).scenarios_per_chunk() == 32  # type: ignore[arg-type]
    assert ClosedLoopConfig(LOG, chunk_size=5).scenarios_per_chunk(dual_rate=True) == 5  # type: ignore[arg-type]
    many = traffic.take(np.tile(np.arange(len(traffic)), 8))  # 320 scenarios
    for dual_rate, most in ((False, 256), (True, 32)):
        sizes = [len(t.indices) for t in make_tasks(many, ClosedLoopConfig(LOG), dual_rate=dual_rate)]  # type: ignore[arg-type]
        assert sum(sizes) == len(many) and max(sizes) == most
    default = ClosedLoopConfig(LOG, replan_s=0.2)  # type: ignore[arg-type]
    small = replace(default, chunk_size=3)
    a, b = (ClosedLoopChunk.concat(list(run_closed_loop(PlannerSpec.of("sf"), traffic, c))) for c in (default, small))
    a, b = a.take(np.argsort(a.indices)), b.take(np.argsort(b.indices))
    np.testing.assert_allclose(a.ego_xy_m, b.ego_xy_m, atol=1e-9, rtol=0)
    np.testing.assert_allclose(a.plan_xy_m, b.plan_xy_m, atol=1e-9, rtol=0)


def test_the_replay_has_a_key_of_its_own_and_sumo_keeps_its_key() -> None:
    replay = mode_settings(ClosedLoopConfig(LOG))  # type: ignore[arg-type]
    sumo = mode_settings(ClosedLoopConfig(LOG, simulator="sumo"))  # type: ignore[arg-type]
    assert replay == {**sumo, "simulator": "replay"} and "simulator" not in sumo
    assert "simulator" not in mode_settings(ClosedLoopConfig(REACTIVE))  # type: ignore[arg-type]


def test_the_cli_runs_either_simulator_and_keeps_them_apart(tmp_path: Path, traffic: ScenarioBatch) -> None:
    scenarios = tmp_path / "s.arrow"
    save_scenarios(traffic.take(np.arange(6)), scenarios)
    base = ["evaluate", "--scenarios", str(scenarios), "--planner", "sf", "--mode", LOG, "--replan-s", "0.5"]
    replay = runner.invoke(app, [*base, "--out", str(tmp_path / "r")])
    assert replay.exit_code == 0, replay.output
    assert "closed-loop-log (log replay)" in replay.output
    sumo = runner.invoke(app, [*base, "--out", str(tmp_path / "s"), "--simulator", "sumo"])
    assert sumo.exit_code == 0, sumo.output
    rows_r = load_planner_results(tmp_path / "r", "sf").sort_values("scenario_digest")
    rows_s = load_planner_results(tmp_path / "s", "sf").sort_values("scenario_digest")
    assert "sumo_collision" in rows_s and "sumo_collision" not in rows_r
    np.testing.assert_allclose(rows_r["ade_m"], rows_s["ade_m"], atol=1e-5)
    np.testing.assert_array_equal(rows_r["collision"], rows_s["collision"])
    # a directory of one simulator is not resumed with the other
    mixed = runner.invoke(app, [*base, "--out", str(tmp_path / "r"), "--simulator", "sumo"])
    assert mixed.exit_code != 0
    refused = runner.invoke(app, [*base[:-4], "--out", str(tmp_path / "o"), "--simulator", "replay"])
    assert refused.exit_code != 0 and "--simulator" in refused.output and "closed-loop modes only" in refused.output
