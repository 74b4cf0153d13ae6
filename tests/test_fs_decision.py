"""``letspi-fs`` runs the decision step its configuration names, as ``letspi-fast`` does (scripted model)."""

from __future__ import annotations

from pathlib import Path

from letspi.assembly.build import Builder
from letspi.assembly.planners import build_planner, resolve_planner
from letspi.method.memory import MemoryBank
from letspi.planners.options import PlannerOptions
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import concat_batches


def test_fs_with_the_decision_step_keeps_the_defaults_below_the_gate(tmp_path: Path) -> None:
    MemoryBank.open(tmp_path / "m.sqlite").close()
    options = PlannerOptions(goals="kinematic", memory=tmp_path / "m.sqlite", fast_llm="scripted:default",
                             decide=True, gate_threshold=1.01, llm_cache=False)
    config = resolve_planner("letspi-fs", options)
    assert config.decision is not None  # type: ignore[attr-defined]
    planner = build_planner(config, "FS", builder=Builder(cache=None)).planner
    assert planner.phase.decider is not None  # type: ignore[attr-defined]
    batch = concat_batches([
        straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(22.0, 29.0)], scenario_id="leader"),
        straight_road_scenario(ego_speed_mps=30.0, scenario_id="free")]).history()
    plans = planner.plan(batch)
    assert list(plans.info["decision"]) == ["default", "default"] and not plans.info["consulted"].any()
    assert plans.info["llm_calls"].sum() == 0  # the gate never fires: no model call
