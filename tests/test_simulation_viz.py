"""The closed-loop panel, drawn from a real closed-loop run and the open-loop plan of the same scenario."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_simulation_support import BrakePlanner, as_built

from letspi.constants import T0_INDEX
from letspi.metrics.compute import compute_metrics
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.simulation import ClosedLoopChunk, ClosedLoopConfig, chunk_metrics, run_closed_loop
from letspi.viz.closed_loop import LoopOutcome, plot_closed_loop_panel

pytestmark = pytest.mark.sumo


def test_panel_shows_open_and_closed_loop_outcomes(tmp_path: Path) -> None:
    batch = straight_road_scenario(
        ego_speed_mps=30.0, neighbours=[VehicleSpec(-29.5, 30.0), VehicleSpec(20.0, 31.0, lane_offset=1)],
        scenario_id="viz",
    )
    planner = BrakePlanner(8.0)
    plan = planner.plan(batch)
    opened = compute_metrics(batch, plan.xy_m, plan.vxy_mps)
    reactive = ClosedLoopConfig(mode="closed-loop-reactive")  # type: ignore[arg-type]
    chunk = ClosedLoopChunk.concat(list(run_closed_loop(as_built(planner), batch, reactive)))  # type: ignore[arg-type]
    closed = chunk_metrics(batch, chunk)
    assert opened.collision[0] and not closed.collision[0]
    fut = slice(T0_INDEX + 1, None)
    open_row = LoopOutcome("open loop (recorded neighbours)", plan.xy_m[0], batch.nbr_xy_m[0, :, fut],
                           batch.nbr_valid[0, :, fut], plan.xy_m[:1][:, :, :], np.array([0]),
                           int(opened.collision_step[0]), int(opened.collision_nbr[0]), {"collision": "yes"})
    closed_row = LoopOutcome("closed-loop-reactive", chunk.ego_xy_m[0], chunk.nbr_xy_m[0], chunk.nbr_valid[0],
                             chunk.plan_xy_m[0], chunk.replan_step, notes={"collision": "no"})
    fig = plot_closed_loop_panel(open_row, closed_row, marking_y_m=batch.marking_y_m[0],
                                 marking_is_edge=batch.marking_is_edge[0], ego_length_m=4.5, ego_width_m=1.8,
                                 nbr_length_m=batch.nbr_length_m[0], nbr_width_m=batch.nbr_width_m[0], title="brake")
    gids = {a.get_gid() for ax in fig.axes for a in [*ax.lines, *ax.patches]}
    assert {"ego_path:0", "ego_path:1", "plan:0:0", "collision:0", "replan:1", "nbr_path:1:0"} <= gids
    assert {f"plan:1:{r}" for r in range(5)} <= gids and "collision:1" not in gids
    replans = next(line for line in fig.axes[1].lines if line.get_gid() == "replan:1")
    np.testing.assert_allclose(replans.get_xydata()[1:], chunk.ego_xy_m[0, chunk.replan_step[1:] - 1])
    fig.savefig(tmp_path / "panel.png")
    assert (tmp_path / "panel.png").stat().st_size > 10_000
