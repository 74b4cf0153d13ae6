"""The deciding planners end to end: ``sf-check`` and ``letspi-fast`` with the decision step (scripted model)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from letspi.assembly.build import Builder
from letspi.assembly.planners import build_planner, resolve_planner
from letspi.method.memory import MemoryBank
from letspi.planners.decision import DECISION_COLUMNS
from letspi.planners.options import PlannerOptions
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import concat_batches

OPTS = PlannerOptions(goals="kinematic")


def _scenes():  # type: ignore[no-untyped-def]
    return concat_batches([
        straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(22.0, 29.0)], scenario_id="leader"),
        straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(-40.0, 30.0, lane_offset=1)],
                               scenario_id="free"),
    ]).history()


def test_sf_check_keeps_the_defaults_where_the_gate_does_not_fire_and_records_its_decisions() -> None:
    batch = _scenes()
    never = build_planner(resolve_planner("sf-check", OPTS.replace(gate_threshold=1.01)), "sf-check",
                          builder=Builder(cache=None))
    plans = never.planner.plan(batch)
    assert set(DECISION_COLUMNS) <= set(plans.info)
    assert list(plans.info["decision"]) == ["default", "default"] and not plans.info["consulted"].any()
    assert np.all((plans.info["risk_score"] >= 0) & (plans.info["risk_score"] <= 1))
    sf = build_planner(resolve_planner("sf", OPTS), "sf", builder=Builder(cache=None)).planner.plan(batch)
    np.testing.assert_allclose(plans.xy_m, sf.xy_m, atol=1e-9)  # the defaults are sf's plan
    assert plans.info["adverse_failed"][0] == "leader-brakes" and plans.info["adverse_failed"][1] == ""
    always = build_planner(resolve_planner("sf-check", OPTS.replace(gate=False)), "sf-check",
                           builder=Builder(cache=None))
    ruled = always.planner.plan(batch)
    assert ruled.info["consulted"].all()
    assert ruled.info["decision"][0] != "default"  # the defaults fail leader-brakes: the rule takes a preset
    assert ruled.info["decision"][1] == "default"  # nothing fails on a free road
    assert "default fails leader-brakes; chose " in ruled.info["reason"][0]
    assert ruled.info["reason"][1].endswith("default passes every check; kept default")
    assert " < gate " in plans.info["reason"][0]


def test_decision_off_reproduces_the_planner_and_its_key(tmp_path: Path) -> None:
    MemoryBank.open(tmp_path / "m.sqlite").close()
    base = OPTS.replace(memory=tmp_path / "m.sqlite", fast_llm="scripted:default")
    off = resolve_planner("letspi-fast", base)
    assert off.decision is None  # type: ignore[attr-defined]
    assert "decision" not in off.identity()
    on = resolve_planner("letspi-fast", base.replace(decide=True))
    assert on.key() != off.key() and on.decision is not None  # type: ignore[attr-defined]
    with pytest.raises(ValueError, match="choice prompt style needs"):
        resolve_planner("letspi-fast", base.replace(prompt_style="choice", decide=False))


def test_the_shield_reuses_sf_check_s_preset_checks_and_plans_the_same() -> None:
    """``sf-check`` hands its checks of every preset to the shield (``Proposals.extra``), which otherwise
    checks them again for the plans it replaces: the same alternatives, so the same plans."""
    from dataclasses import replace

    from letspi.planners.llm import PRESETS_PASS_ALL, PRESETS_PROGRESS

    batch = concat_batches([
        straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(gap, 29.0 - drop)], scenario_id=f"s{i}")
        for i, (gap, drop) in enumerate([(22.0, 0.0), (12.0, 6.0), (8.0, 10.0), (40.0, 2.0)])
    ]).history()
    planner = build_planner(resolve_planner("sf-check", OPTS.replace(gate=False)), "sf-check",
                            builder=Builder(cache=None)).planner
    context = planner.context(batch)
    proposals = planner.propose(batch, context)
    assert proposals.extra[PRESETS_PASS_ALL].shape == proposals.extra[PRESETS_PROGRESS].shape == (4, 6)
    reused = planner.simulate(batch, context, proposals)
    checked_again = planner.simulate(batch, context, replace(proposals, extra={}))
    assert reused.info["shield_source"].tolist() == checked_again.info["shield_source"].tolist()
    assert (reused.info["shield_source"] != "").any()  # the case must be one where the shield acts
    np.testing.assert_array_equal(reused.xy_m, checked_again.xy_m)


def test_where_the_decision_step_keeps_the_defaults_the_planner_plans_exactly_as_sf() -> None:
    """The shield's replacements of the decision step's presets (sf-opt's grid, a memory, another preset) cost
    contacts and success on the held-out suites (notes/model_earns.md): by default it leaves them alone, so a
    window the step keeps is sf's, and a chosen preset is that preset's plan; ``--shield-presets`` restores the
    shield there."""
    batch = concat_batches([
        straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(gap, 29.0 - drop)], scenario_id=f"s{i}")
        for i, (gap, drop) in enumerate([(22.0, 0.0), (10.0, 8.0), (14.0, 12.0), (40.0, 2.0)])
    ]).history()
    never = OPTS.replace(gate_threshold=1.01)  # the gate keeps the defaults everywhere
    sf = build_planner(resolve_planner("sf", OPTS), "sf", builder=Builder(cache=None)).planner.plan(batch)
    kept = build_planner(resolve_planner("sf-check", never), "sf-check",
                         builder=Builder(cache=None)).planner.plan(batch)
    assert list(kept.info["decision"]) == ["default"] * 4 and not kept.info["shielded"].any()
    np.testing.assert_array_equal(kept.xy_m, sf.xy_m)
    shielding = resolve_planner("sf-check", never.replace(shield_presets=True))
    assert shielding.key() != resolve_planner("sf-check", never).key()
    shielded = build_planner(shielding, "sf-check", builder=Builder(cache=None)).planner.plan(batch)
    assert shielded.info["shielded"].any()  # the case is one where the shield would act on the defaults
    rows = shielded.info["shielded"] > 0
    assert np.abs(shielded.xy_m[rows] - sf.xy_m[rows]).max() > 0.1
    np.testing.assert_array_equal(shielded.xy_m[~rows], sf.xy_m[~rows])
    # every preset the rule picks is planned as it is: the plan of the preset's own parameters
    ruled = build_planner(resolve_planner("sf-check", OPTS.replace(gate=False)), "sf-check",
                          builder=Builder(cache=None)).planner
    plans = ruled.plan(batch)
    assert not plans.info["shielded"].any() and (plans.info["decision"] != "default").any()
    context = ruled.context(batch)  # type: ignore[attr-defined]
    checks = ruled.decider.check(batch, context.goals_xy_m, context.neighbours)  # type: ignore[attr-defined]
    chosen = [checks.names.index(d) for d in plans.info["decision"]]
    np.testing.assert_array_equal(plans.xy_m, checks.xy_m[np.arange(len(batch)), chosen])
