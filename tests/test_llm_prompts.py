"""Scenario description and prompt rendering (Fig. 2 layouts, static prefix, memories, reflection)."""

from __future__ import annotations

import dataclasses
import json
from importlib import resources

import numpy as np
import pytest

from letspi.constants import T0_INDEX
from letspi.llm.describe import describe_scenario, targeted_guidance
from letspi.llm.parse import parse_reply
from letspi.llm.prompts import MemoryExample, render_fast_prompt, render_physics_prompt, system_prompt
from letspi.llm.schema import DEFAULT_REPLY, WIRE_KEYS
from letspi.scenario.build import VehicleSpec, straight_road_scenario


def scenario(*nbrs: VehicleSpec, **kw: object):  # type: ignore[no-untyped-def]
    return straight_road_scenario(neighbours=list(nbrs), **kw)  # type: ignore[arg-type]


def test_relations_gaps_ttc_and_lanes() -> None:
    scn = scenario(
        VehicleSpec(25.0, 24.0),  # ahead, closing at 6 m/s
        VehicleSpec(-30.0, 33.0),  # behind, closing at 3 m/s
        VehicleSpec(2.0, 30.0, lane_offset=1),  # beside on the left
        VehicleSpec(40.0, 35.0, lane_offset=-1),  # right, ahead
    )
    d = describe_scenario(scn, (150.0, 0.0))
    rel = {n.vehicle_id: n for n in d.neighbours}
    assert (
        rel[2].relation == "ahead" and rel[2].gap_m == pytest.approx(20.5) and rel[2].ttc_s == pytest.approx(20.5 / 6)
    )
    assert rel[3].relation == "behind" and rel[3].ttc_s == pytest.approx(25.5 / 3)
    assert rel[4].relation == "left-alongside" and rel[4].lane_offset == 1 and rel[4].ttc_s is None
    assert rel[5].relation == "right-ahead" and rel[5].lane_offset == -1
    assert d.neighbours[0].vehicle_id == 4  # sorted by distance
    assert [ln.lane_id for ln in d.lanes] == [8, 7, 6] and d.ego_lane == 7 and d.goal_lane == 7
    assert d.lane_left_of(7) == 6 and d.lane_right_of(7) == 8 and d.lane_left_of(6) is None
    assert d.leader() is rel[2] and d.follower() is rel[3]
    assert [p.t for p in d.ego_history] == pytest.approx([-2.52, -2.0, -1.52, -1.0, -0.52], abs=1e-6)


def test_text_is_short_and_rounded() -> None:
    d = describe_scenario(scenario(VehicleSpec(25.0, 24.0)), (150.0, 0.0))
    full, brief = d.to_text(), d.to_text(detail="brief")
    assert "pos (25.0, 0.0)" in full and "TTC 3.4 s" in full and "edge (never cross)" in full
    assert "History" in full and "History" not in brief and "past" not in brief
    assert "-0.0" not in full
    assert len(brief) < len(full) < 2000


def test_description_ignores_the_future() -> None:
    scn = scenario(VehicleSpec(25.0, 24.0))
    xy = scn.nbr_xy_m.copy()
    xy[:, T0_INDEX + 1 :] = 999.0
    changed = dataclasses.replace(
        scn, nbr_xy_m=xy, ego_xy_m=np.where(np.arange(200)[:, None] > T0_INDEX, -5, scn.ego_xy_m)
    )
    assert describe_scenario(changed, (150.0, 0.0)) == describe_scenario(scn, (150.0, 0.0))


def test_invisible_neighbours_are_left_out() -> None:
    scn = scenario(VehicleSpec(25.0, 24.0, visible_from_index=T0_INDEX + 5), VehicleSpec(-20.0, 30.0))
    d = describe_scenario(scn, (150.0, 0.0))
    assert [n.vehicle_id for n in d.neighbours] == [3]


def test_targeted_guidance() -> None:
    close = describe_scenario(scenario(VehicleSpec(15.0, 22.0)), (150.0, 0.0))
    assert any("raise k_np and shorten the goal" in g for g in targeted_guidance(close))
    free = describe_scenario(scenario(), (150.0, 0.0))
    assert any("No conflict" in g for g in targeted_guidance(free))
    beside = describe_scenario(scenario(VehicleSpec(1.0, 30.0, lane_offset=-1)), (150.0, 0.0))
    assert any("beside on the right" in g for g in targeted_guidance(beside))
    left_lane = describe_scenario(scenario(ego_lane_index=2), (150.0, 0.0))
    assert any("No lane to the left" in g for g in targeted_guidance(left_lane))
    follower = describe_scenario(scenario(VehicleSpec(-12.0, 38.0)), (150.0, 0.0))
    assert any("raise k_nf" in g for g in targeted_guidance(follower))


def test_templates_are_package_data() -> None:
    names = {p.name for p in resources.files("letspi").joinpath("prompts").iterdir()}
    assert {"physics_system.j2", "physics_user.j2", "refinement.j2", "fast_system.j2", "fast_user.j2"} <= names


def test_physics_prompt_layout_and_static_prefix() -> None:
    a = describe_scenario(scenario(VehicleSpec(25.0, 24.0)), (150.0, 0.0))
    b = describe_scenario(scenario(VehicleSpec(60.0, 30.0, lane_offset=1)), (140.0, 3.75))
    pa, pb = render_physics_prompt(a), render_physics_prompt(b)
    assert [m["role"] for m in pa] == ["system", "user"]
    assert pa[0] == pb[0] and pa[0]["content"] == system_prompt("physics")  # identical static prefix
    sys_text = pa[0]["content"]
    for needle in (
        "## Role",
        "## Context",
        "## Inputs",
        "## Social force model",
        "## Safety constraints",
        "## Output format",
        "k_np",
        "0 to 60",
        "exp(-d_j / r_col)",
        "y points to the left",
    ):
        assert needle in sys_text
    for key in WIRE_KEYS.values():
        assert f'"{key}"' in sys_text
    assert "Scenario" not in sys_text.split("## Inputs")[0]  # no scenario data in the static part
    assert pa[1]["content"].startswith("## Scenario summary") and "Memory" not in pa[1]["content"]


def test_physics_prompt_memory_and_reflection() -> None:
    d = describe_scenario(scenario(VehicleSpec(15.0, 22.0)), (150.0, 0.0))
    mem = [MemoryExample("3 lanes, leader gap 12 m", DEFAULT_REPLY, "min TTC 3.1 s")]
    msgs = render_physics_prompt(d, memories=mem)
    assert "## Memory" in msgs[1]["content"] and "min TTC 3.1 s" in msgs[1]["content"]
    answer = msgs[1]["content"].split("min TTC 3.1 s): ")[1].splitlines()[0]
    assert parse_reply(answer).reply.params() == DEFAULT_REPLY.params()  # examples are valid replies
    report = "t=2.1 s, lane 7: TTC 1.1 s to #2 ahead"
    one = render_physics_prompt(d, safety_report=report)
    assert len(one) == 2 and "## Safety analysis report" in one[1]["content"] and report in one[1]["content"]
    prev = json.dumps(DEFAULT_REPLY.to_wire())
    multi = render_physics_prompt(d, memories=mem, safety_report=report, previous_reply=prev)
    assert [m["role"] for m in multi] == ["system", "user", "assistant", "user"]
    assert multi[:2] == msgs  # the first exchange is a reusable prefix
    assert (
        multi[2]["content"] == prev
        and report in multi[3]["content"]
        and "Prioritise longitudinal" in multi[3]["content"]
    )


def test_fast_prompt() -> None:
    d = describe_scenario(scenario(VehicleSpec(15.0, 22.0)), (150.0, 0.0))
    mems = [MemoryExample(f"example {i}", DEFAULT_REPLY) for i in range(3)]
    msgs = render_fast_prompt(d, memories=mems)
    assert [m["role"] for m in msgs] == ["system", "user"] and msgs[0]["content"] == system_prompt("fast")
    user = msgs[1]["content"]
    assert user.count("Answer: {") == 3 and '"why"' not in user
    assert "## Guidance" in user and "raise k_np" in user and user.rstrip().endswith("Answer:")
    assert user.index("Example 1") < user.index("## Current scenario")  # scenario last
    assert len(msgs[0]["content"]) < len(system_prompt("physics")) / 2
    plain = render_fast_prompt(d, guidance=[])
    assert "## Guidance" not in plain[1]["content"] and "Example" not in plain[1]["content"]


def test_static_examples_stay_inside_the_prefix_servers_cache() -> None:
    """letspi-fs sends the same three examples with every scene: they come before the scene, so the
    prefix two requests share (what vLLM's prefix caching and llama.cpp reuse) covers the system
    message and every example; only the scene and its guidance differ."""
    a = describe_scenario(scenario(VehicleSpec(25.0, 24.0)), (150.0, 0.0))
    b = describe_scenario(scenario(VehicleSpec(60.0, 30.0, lane_offset=1)), (140.0, 3.75))
    mems = [MemoryExample(f"example {i}", DEFAULT_REPLY, f"min TTC {i + 2}.0 s") for i in range(3)]
    fa, fb = render_fast_prompt(a, memories=mems), render_fast_prompt(b, memories=mems)
    ta, tb = "\n".join(m["content"] for m in fa), "\n".join(m["content"] for m in fb)
    shared = ta[: next(i for i, (x, y) in enumerate(zip(ta, tb, strict=False)) if x != y)]
    assert shared.startswith(system_prompt("fast")) and "min TTC 4.0 s" in shared  # all three examples
    assert "## Current scenario" in shared and len(shared) < len(ta)  # the first difference is in the scene


def test_units_come_from_the_physics_module() -> None:
    from letspi.llm.schema import FIELD_DOCS, LLM_PARAM_RANGES
    from letspi.physics.params import PARAM_UNITS

    assert PARAM_UNITS["k_boundary"] == "m^3/s^2" and PARAM_UNITS["k_cline"] == "m^2/s^2"
    for name in LLM_PARAM_RANGES:
        assert FIELD_DOCS[name][0] == PARAM_UNITS[name], name
    physics = system_prompt("physics")
    lines = {line.split(":")[0]: line for line in physics.splitlines() if line.startswith("- ")}
    for name in LLM_PARAM_RANGES:
        assert f"({PARAM_UNITS[name]}, " in lines[f"- {WIRE_KEYS[name]}"], name
    # the lane-marking equations state the same units, never m/s^2 for k_bd or k_cl
    assert "k_bd in m^3/s^2" in physics and "k_cl in m^2/s^2" in physics
    fast = system_prompt("fast")
    for name in LLM_PARAM_RANGES:
        lo, hi = LLM_PARAM_RANGES[name]
        assert f"{WIRE_KEYS[name]} {lo:g} to {hi:g} {PARAM_UNITS[name]}" in fast, name
    for line in physics.splitlines():
        if "k_bd" in line or "k_cl" in line:
            assert "m/s^2" not in line, line
