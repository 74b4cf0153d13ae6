"""Closed loop, dual rate: a preset held since an earlier model call gives way to the defaults once the scene no
longer calls for it (``LetsPiFastPlanner.release_held``, ``DualRateConfig.release``)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from letspi.assembly.build import Builder
from letspi.assembly.planners import build_planner, resolve_planner
from letspi.method.decide import load_presets
from letspi.method.memory import MemoryBank
from letspi.physics.params import SocialForceParams
from letspi.planners.base import Proposals
from letspi.planners.llm import with_rows
from letspi.planners.options import PlannerOptions
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import concat_batches
from letspi.simulation.schedule import DualRateConfig


def _scenes():  # type: ignore[no-untyped-def]
    """A leader 22 m ahead (the defaults fail leader-brakes) and a free road (they pass every check)."""
    return concat_batches([
        straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(22.0, 29.0)], scenario_id="leader"),
        straight_road_scenario(ego_speed_mps=30.0, neighbours=[VehicleSpec(-40.0, 30.0, lane_offset=1)],
                               scenario_id="free"),
    ]).history()


def _planner(tmp_path: Path, **options: object):  # type: ignore[no-untyped-def]
    MemoryBank.open(tmp_path / "m.sqlite").close()
    opts = PlannerOptions(goals="kinematic", memory=tmp_path / "m.sqlite", fast_llm="scripted:default", decide=True,
                          **options)
    return build_planner(resolve_planner("letspi-fast", opts), "letspi-fast", builder=Builder(cache=None)).planner


def _holding(planner, batch, decisions):  # type: ignore[no-untyped-def]
    """The defaults' proposals with the presets ``decisions`` held (their goal factors and decision)."""
    proposals = planner.default_proposals(batch)
    table, _ = load_presets()
    lon = np.array([table.values_of(d)["lon_factor"] for d in decisions])
    lane = np.array([table.values_of(d)["lane_factor"] for d in decisions])
    info = {**proposals.info, "decision": np.array(decisions, dtype=object), "lon_factor": lon}
    return replace(proposals, lon_factor=lon, lane_factor=lane, info=info)


def test_a_held_preset_is_released_only_where_the_scene_no_longer_calls_for_it(tmp_path):
    batch = _scenes()
    planner = _planner(tmp_path, gate_threshold=0.0)  # the gate fires everywhere
    context = planner.context(batch)
    held = _holding(planner, batch, ["brake", "brake"])
    out, released = planner.release_held(batch, context, held)
    # the leader's scene: the defaults still fail leader-brakes, so brake stays; the free road: released
    assert released.tolist() == [False, True]
    assert out.info["decision"].tolist() == ["brake", "default"]
    defaults = planner.default_proposals(batch)
    assert out.lon_factor[0] == held.lon_factor[0] and out.lon_factor[1] == defaults.lon_factor[1]
    np.testing.assert_array_equal(out.params.as_matrix()[1], defaults.params.as_matrix()[1])

    quiet = _planner(tmp_path, gate_threshold=1.01)  # the gate never fires: every held preset gives way
    assert quiet.release_held(batch, context, held)[1].tolist() == [True, True]
    # against the prediction alone the leader's defaults are safe too (only leader-brakes fails)
    assert planner.release_held(batch, context, held, "prediction")[1].tolist() == [True, True]
    # the defaults and a model's own numbers are never touched
    defaults = quiet.default_proposals(batch)
    custom = replace(defaults, info={**defaults.info, "decision": np.array(["custom", "custom"], dtype=object)})
    for proposals in (defaults, custom):
        assert not quiet.release_held(batch, context, proposals)[1].any()


def test_with_rows_replaces_exactly_the_given_rows():
    def props(lon: float, name: str) -> Proposals:
        return Proposals(params=SocialForceParams.from_matrix(np.full((2, 7), lon)), lon_factor=np.full(2, lon),
                         lane_factor=np.zeros(2), info={"decision": np.array([name, name], dtype=object),
                                                        "only_here": np.ones(2)}, extra={"x": np.arange(2)})

    a, b = props(0.4, "brake"), props(0.7, "default")
    out = with_rows(a, np.array([False, True]), b.take([1]))
    assert out.lon_factor.tolist() == [0.4, 0.7] and out.info["decision"].tolist() == ["brake", "default"]
    assert out.params.as_matrix()[:, 0].tolist() == [0.4, 0.7] and out.extra["x"].tolist() == [0, 1]
    assert out.info["only_here"].tolist() == [1.0, 1.0]


def test_release_joins_the_dual_rate_identity_only_when_on():
    on, off = DualRateConfig(2.5, 1.5), DualRateConfig(2.5, 1.5, release="off")
    assert on.identity() == {"llm_period_s": 2.5, "llm_latency_s": 1.5, "release": "checks"}
    assert off.identity() == {"llm_period_s": 2.5, "llm_latency_s": 1.5}  # the key of results made before release
    with pytest.raises(ValueError, match="--release must be one of"):
        DualRateConfig(release="sometimes")
