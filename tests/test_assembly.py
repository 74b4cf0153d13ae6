"""Configuration identity: everything that changes an answer changes the key, nothing else does."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from letspi.assembly.build import Builder, ConfigurationChangedError
from letspi.assembly.planners import build_planner, build_planners, parse_planner_arg, resolve_planner
from letspi.assembly.resolve import Resolver
from letspi.keyed import diff
from letspi.learned.weights import shipped_weights_dir
from letspi.llm.cache import ResponseCache
from letspi.method.memory import MemoryBank
from letspi.method.phases import collect
from letspi.physics.params import SocialForceParams
from letspi.planners.config import GOAL_WEIGHTS_ENV
from letspi.planners.gnp import GNP_WEIGHTS_ENV
from letspi.planners.options import PlannerOptions
from letspi.planners.sf import SfConfig
from letspi.planners.sf_params import save_sf_params
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.types import concat_batches

OPTS = PlannerOptions(llm="scripted:default", fast_llm="scripted:default", llm_cache=False)


def _key(kind: str, options: PlannerOptions = OPTS, env: dict[str, str] | None = None) -> str:
    return resolve_planner(kind, options, env=env or {}).key()


def test_the_key_is_stable_and_cosmetic_fields_do_not_count(tmp_path: Path) -> None:
    assert _key("sf") == _key("sf")
    # the same parameter values from another file: same answers, same key (the file is recorded, not hashed)
    path = save_sf_params(tmp_path / "copy.json", Resolver(OPTS).sf_params.params(), {}, {})
    copy = resolve_planner("sf", OPTS.replace(sf_params_file=path))
    assert copy.key() == _key("sf") and isinstance(copy, SfConfig) and copy.sf_params.source == str(path)
    # the response cache switch cannot change an answer
    assert _key("letspi-memory", OPTS.replace(llm_cache=True)) == _key("letspi-memory")


@pytest.mark.parametrize("kind", ["sf", "sf-opt", "letspi-memory", "llm"])
def test_neighbour_mode_goals_and_parameter_values_change_the_key(kind: str, tmp_path: Path) -> None:
    """0.1 dropped the neighbour mode and SF parameters from the LLM planners' key, and `--goals` from the
    memory key."""
    base = _key(kind)
    assert _key(kind, OPTS.replace(neighbour_mode="constant_velocity")) != base
    assert _key(kind, OPTS.replace(goals="kinematic")) != base
    other = save_sf_params(tmp_path / "other.json", SocialForceParams(k_np=21.0), {}, {})
    assert _key(kind, OPTS.replace(sf_params_file=other)) != base


def test_collection_key_depends_on_goals_iterations_and_goal_adjustment() -> None:
    base = Resolver(OPTS).memory_phase().key()
    assert Resolver(OPTS.replace(goals="kinematic")).memory_phase().key() != base
    assert Resolver(OPTS).memory_phase(max_iterations=1).key() != base
    assert Resolver(OPTS.replace(goal_adjustment=False)).memory_phase().key() != base
    assert Resolver(OPTS.replace(llm="scripted:default")).memory_phase().key() == base


def test_goal_and_gnp_weight_environment_variables_are_part_of_the_key(tmp_path: Path) -> None:
    """0.1 read $LETSPI_GOAL_WEIGHTS inside the learned package and recorded it nowhere."""
    other_goals = tmp_path / "goal"
    shutil.copytree(shipped_weights_dir("goal"), other_goals)
    manifest = json.loads((other_goals / "manifest.json").read_text())
    (other_goals / "manifest.json").write_text(json.dumps({**manifest, "note": "retrained"}))
    for kind in ("sf", "gnp", "letspi-memory"):
        assert _key(kind, env={GOAL_WEIGHTS_ENV: str(other_goals)}) != _key(kind), kind
    assert _key("gnp", env={GOAL_WEIGHTS_ENV: str(shipped_weights_dir("goal"))}) == _key("gnp")
    other_gnp = tmp_path / "gnp"
    shutil.copytree(shipped_weights_dir("gnp"), other_gnp)
    manifest = json.loads((other_gnp / "manifest.json").read_text())
    (other_gnp / "manifest.json").write_text(json.dumps({**manifest, "note": "retrained"}))
    assert _key("gnp", env={GNP_WEIGHTS_ENV: str(other_gnp)}) != _key("gnp")


def test_model_weights_fingerprint_for_local_models(tmp_path: Path) -> None:
    gguf = tmp_path / "m.gguf"
    gguf.write_bytes(b"GGUF" + bytes(100))
    a = Resolver(OPTS).llm(f"llamacpp:{gguf}")
    gguf.write_bytes(b"GGUF" + bytes(99) + b"\x01")
    b = Resolver(OPTS).llm(f"llamacpp:{gguf}")
    assert a.model_sha256 != b.model_sha256 and a.key() != b.key() and a.spec == b.spec
    assert Resolver(OPTS).llm("ollama:llama3.1:8b").model_sha256 is None  # served weights: the name identifies


def test_fast_planner_key_pins_the_memory_snapshot(tmp_path: Path) -> None:
    from letspi.llm.backends.scripted import ScriptedBackend
    from letspi.llm.client import ParamAdvisor
    from letspi.method.phases import MemoryPhase
    from letspi.physics.goals import KinematicGoalPredictor

    reply = json.dumps({"why": "x", "tau": 2.0, "k_np": 40, "k_nf": 3, "k_nl": 0.5, "k_bd": 1, "k_cl": 0.5,
                        "lon": 0.8, "lane": 0})
    phase = MemoryPhase(ParamAdvisor(ScriptedBackend(default=reply), cache=None), KinematicGoalPredictor(), 10.0,
                        config_key="k")
    mem = tmp_path / "m.sqlite"
    scenes = [straight_road_scenario(ego_speed_mps=28.0 + i, scenario_id=f"s{i}") for i in range(3)]
    with MemoryBank.open(mem) as bank:
        collect(phase, concat_batches(scenes[:2]), bank)
    options = OPTS.replace(memory=mem)
    config = resolve_planner("letspi-fast", options)
    built = build_planner(config, builder=Builder(cache=None))
    assert built.planner.phase.retriever.allowed_ids.tolist() == [1, 2]  # type: ignore[attr-defined]
    assert _key("letspi-fast", options.replace(allow_same_vehicle=True)) != config.key()
    assert _key("letspi-fast", options.replace(top_k=5)) != config.key()
    with MemoryBank.open(mem) as bank:
        collect(phase, scenes[2], bank)
    assert _key("letspi-fast", options) != config.key()  # a grown bank is another configuration
    with pytest.raises(ConfigurationChangedError, match="2 -> 3 retrievable memories"):
        build_planner(config, builder=Builder(cache=None))


def test_diff_names_the_changed_fields() -> None:
    a = resolve_planner("sf", OPTS)
    b = resolve_planner("sf", OPTS.replace(neighbour_mode="constant_velocity", goals="kinematic"))
    changes = diff(a.identity(), b.identity())
    assert "neighbours: idm -> constant_velocity" in changes
    assert any(c.startswith("goals.source: learned -> kinematic") for c in changes)


def test_planner_labels() -> None:
    assert parse_planner_arg("sf") == ("sf", "sf")
    assert parse_planner_arg("sf-cv=sf") == ("sf-cv", "sf")
    with pytest.raises(ValueError, match="LABEL=KIND"):
        parse_planner_arg("=sf")
    with pytest.raises(ValueError, match="given twice"):
        build_planners(["sf", "sf"], OPTS)


def test_llm_planner_rows_say_whether_the_cache_answered(tmp_path: Path) -> None:
    """0.1 reported a cache hit's 0.015 s as inference time with no way to tell."""
    batch = straight_road_scenario(ego_speed_mps=33.0, neighbours=[VehicleSpec(x0_m=40.0, speed_mps=20.0)])
    cache = ResponseCache(tmp_path / "cache.sqlite")
    options = OPTS.replace(llm_cache=True, max_iterations=0)
    first = build_planner(resolve_planner("llm", options), builder=Builder(cache=cache)).planner.plan(batch.history())
    again = build_planner(resolve_planner("llm", options), builder=Builder(cache=cache)).planner.plan(batch.history())
    assert not first.info["llm_cached"][0] and again.info["llm_cached"][0]
    assert again.info["llm_latency_s"][0] == 0.0
    assert again.info["llm_original_latency_s"][0] == pytest.approx(first.info["llm_latency_s"][0], abs=1e-3)
    np.testing.assert_array_equal(first.xy_m, again.xy_m)


def test_a_configuration_without_the_cache_never_gets_a_cached_answer_from_a_shared_builder(tmp_path: Path) -> None:
    """The demo built its head-to-head (``llm_cache=False``) with the collect phase's builder and got
    the cached advisor back: letspi-fast was never timed. The cache switch is not in the key, so the
    builder must tell them apart itself."""
    batch = straight_road_scenario(ego_speed_mps=33.0, neighbours=[VehicleSpec(x0_m=40.0, speed_mps=20.0)])
    builder = Builder(cache=ResponseCache(tmp_path / "cache.sqlite"))
    cached = OPTS.replace(llm_cache=True, max_iterations=0)
    uncached = OPTS.replace(llm_cache=False, max_iterations=0)
    first = build_planner(resolve_planner("llm", cached), builder=builder).planner.plan(batch.history())
    assert resolve_planner("llm", cached).key() == resolve_planner("llm", uncached).key()
    again = build_planner(resolve_planner("llm", uncached), builder=builder).planner.plan(batch.history())
    assert not first.info["llm_cached"][0] and not again.info["llm_cached"][0]
    np.testing.assert_array_equal(first.xy_m, again.xy_m)
