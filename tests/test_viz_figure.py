"""Scenario figures: what is drawn must be the data (plan lines, lane markings, goals, gaps, text)."""

from __future__ import annotations

import io
import json

import matplotlib

matplotlib.use("Agg")

import numpy as np
import pytest
from matplotlib.image import imread
from matplotlib.lines import Line2D
from matplotlib.text import Text

from letspi.constants import N_TOTAL, T0_INDEX
from letspi.planners.base import PlanBatch
from letspi.planners.cv import ConstantVelocityPlanner
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.viz.data import neighbour_groups, preceding_gap
from letspi.viz.figure import plot_scenario
from letspi.viz.llm_panel import IterationRecord, load_iterations, wrap_text


def _batch():
    return straight_road_scenario(
        scenario_id="viz0",
        neighbours=[VehicleSpec(20.0, 30.0), VehicleSpec(-15.0, 32.0, lane_offset=1), VehicleSpec(5.0, 28.0, -1)],
    )


def _by_gid(fig, gid: str):
    found = fig.findobj(lambda a: a.get_gid() == gid)
    assert len(found) == 1, f"{gid}: {len(found)} artists"
    return found[0]


def test_plan_lines_and_markings_are_the_data(tmp_path):
    batch = _batch()
    cv = ConstantVelocityPlanner().plan(batch)
    shifted = PlanBatch(xy_m=cv.xy_m + np.array([0.0, 1.0]), vxy_mps=cv.vxy_mps,
                        goals_xy_m=cv.goals_xy_m + np.array([-20.0, 3.5]))
    out = tmp_path / "fig.png"
    fig = plot_scenario(batch, 0, {"cv": cv, "other": shifted}, out_png=out, goal_xy_m=cv.goals_xy_m[0])
    for name, plan in (("cv", cv), ("other", shifted)):
        line = _by_gid(fig, f"plan:{name}")
        assert isinstance(line, Line2D)
        np.testing.assert_allclose(line.get_xydata(), plan.xy_m[0])
        ts = _by_gid(fig, f"ts:plan:{name}")
        np.testing.assert_allclose(ts.get_ydata(), plan.xy_m[0, :, 0])
        np.testing.assert_allclose(ts.get_xdata(), (np.arange(plan.xy_m.shape[1]) + 1) * 0.04)
    past = _by_gid(fig, "ego_past")
    np.testing.assert_allclose(past.get_xydata(), batch.ego_xy_m[0, : T0_INDEX + 1])
    marks = batch.marking_y_m[0]
    for k, (y, edge) in enumerate(zip(marks, batch.marking_is_edge[0], strict=True)):
        line = _by_gid(fig, f"{'road_edge' if edge else 'lane_line'}:{k}")
        np.testing.assert_allclose(line.get_ydata(), [y, y])
        assert (line.get_linestyle() == "-") == bool(edge)  # crossable lines dashed, edges solid
    # the goal used by "other" differs from the predicted goal: drawn as an adjusted goal; cv's is not
    adj = _by_gid(fig, "adjusted_goal:other")
    np.testing.assert_allclose(adj.get_xydata()[0], shifted.goals_xy_m[0])
    assert not fig.findobj(lambda a: a.get_gid() == "adjusted_goal:cv")
    np.testing.assert_allclose(_by_gid(fig, "goal").get_xydata()[0], cv.goals_xy_m[0])
    # neighbours' boxes at t = 0 with ids
    for vid in batch.nbr_id[0][batch.nbr_valid[0, :, T0_INDEX]]:
        box = _by_gid(fig, f"nbr_box:{vid}")
        np.testing.assert_allclose(box.get_center(), batch.nbr_xy_m[0, list(batch.nbr_id[0]).index(vid), T0_INDEX],
                                   atol=1e-6)
    ax = next(a for a in fig.axes if a.get_label() == "trajectory")
    assert ax.get_aspect() == 1.0
    image = imread(out)
    assert image.shape[0] > 200 and float(image[..., :3].var()) > 0.0


def test_full_batch_plans_use_the_row_and_bad_sizes_fail():
    batch = _batch().take([0, 0, 0])
    plan = ConstantVelocityPlanner().plan(batch)
    fig = plot_scenario(batch, 2, {"cv": plan})
    np.testing.assert_allclose(_by_gid(fig, "plan:cv").get_xydata(), plan.xy_m[2])
    with pytest.raises(ValueError, match="expected 1 or the batch size"):
        plot_scenario(batch, 0, {"cv": PlanBatch(plan.xy_m[:2], plan.vxy_mps[:2], plan.goals_xy_m[:2])})


def test_preceding_gap_and_groups():
    batch = _batch()
    sc = batch.take([0])
    gap, slot = preceding_gap(sc, sc.ego_xy_m[0], np.arange(N_TOTAL))
    # leader 20 m ahead at t = 0, 30 m/s like the ego: gap = 20 - (4.5 + 4.5) / 2 all along
    np.testing.assert_allclose(gap, 15.5, atol=1e-4)
    assert (slot == 0).all()
    assert neighbour_groups(sc)[:4] == ["same lane", "adjacent lane", "adjacent lane", None]


def test_iteration_panels_show_the_text_verbatim():
    batch = _batch()
    rationale = "Keep the lane; the left lane costs $5 and vehicle 7 is alongside. " * 6
    records = [
        IterationRecord(0, "Safety issue detected:\n- Low TTC = 0.7 s\n- Low PET = 1.6 s", rationale,
                        {"k_np": 25.0}, 0.6, 0.0, {"min_ttc_s": 0.7, "min_pet_s": 1.6}),
        IterationRecord(1, "No safety issue.", "Done.", {}, float("nan"), -1.0, {}),
    ]
    fig = plot_scenario(batch, 0, None, records)
    text = _by_gid(fig, "rationale:0")
    assert isinstance(text, Text)
    shown = text.get_text()
    assert " ".join(shown.split()).startswith(" ".join(rationale.split())[:200])
    assert max(len(line) for line in shown.splitlines()) < 120  # wrapped
    assert "goal distance ×0.90" in shown and "k_np = 25" in shown
    report = _by_gid(fig, "safety_report:0").get_text()
    assert "min TTC 0.7 s" in report and "- Low PET = 1.6 s" in report
    assert "towards left lane" in _by_gid(fig, "rationale:1").get_text()
    labels = {a.get_label() for a in fig.axes}
    assert {"safety_report:0", "response:0", "safety_report:1", "response:1"} <= labels
    fig.savefig(io.BytesIO(), format="png")  # renders; "$" must not be parsed as mathtext


def test_wrap_text_cuts_and_iterations_load(tmp_path):
    wrapped = wrap_text("word " * 500, 40, max_lines=5)
    lines = wrapped.splitlines()
    assert len(lines) == 5 and "more line(s) not shown" in lines[-1]
    rec = IterationRecord(2, "r", "why", {"tau_s": 1.0}, 0.5, float("nan"), {"min_ttc_s": 3.0})
    path = tmp_path / "it.json"
    path.write_text(json.dumps([rec.to_dict()]))
    (back,) = load_iterations(path)
    assert back.iteration == 2 and back.params == {"tau_s": 1.0} and np.isnan(back.lane_factor)
