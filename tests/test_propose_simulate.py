"""Propose/simulate split: batched physics gives every planner the plans of per-scenario physics.

The LLM planners answer from the local test server (replies are a hash of the prompt, so any change
of a prompt changes the answer); the physics planners use the shipped goal weights.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from concurrency_support import collect_into, options, scenarios, stored_results

from benchmarks.llm_server import LlmTestServer
from letspi.assembly.planners import BuiltPlanner, build_planners
from letspi.evaluation import concurrent
from letspi.evaluation.harness import EvaluationSettings, evaluate
from letspi.execution.ordered import BlockCache
from letspi.planners.base import PlanBatch, Proposals, ProposingPlanner
from letspi.planners.options import PlannerOptions
from letspi.scenario.types import ScenarioBatch

TIMING_INFO = ("llm_latency_s", "llm_original_latency_s")  # wall times of requests


def _per_scenario(planner: ProposingPlanner, batch: ScenarioBatch) -> list[PlanBatch]:
    return [planner.plan(batch.take([i])) for i in range(len(batch))]


def _assert_same_plans(batched: PlanBatch, singles: list[PlanBatch], atol: float = 1e-9) -> None:
    for name in ("xy_m", "vxy_mps", "goals_xy_m"):
        one_by_one = np.concatenate([getattr(p, name) for p in singles])
        np.testing.assert_allclose(getattr(batched, name), one_by_one, rtol=0, atol=atol, err_msg=name)
    assert set(batched.info) == set(singles[0].info)
    for key, values in batched.info.items():
        if key in TIMING_INFO:
            continue
        np.testing.assert_allclose(np.asarray(values, dtype=np.float64),
                                   np.concatenate([np.asarray(p.info[key], dtype=np.float64) for p in singles]),
                                   rtol=0, atol=atol, err_msg=key)


@pytest.fixture(scope="module")
def llm_setup(tmp_path_factory: pytest.TempPathFactory) -> tuple[LlmTestServer, Path]:
    """The test server and a memory bank collected from it (reflection rounds happen on these scenes)."""
    bank = tmp_path_factory.mktemp("bank") / "bank.sqlite"
    srv = LlmTestServer()
    srv.__enter__()
    collect_into(bank, srv.spec(), scenarios(12, seed=5), concurrency=4)
    yield srv, bank
    srv.__exit__(None, None, None)


def _llm_planners(srv: LlmTestServer, bank: Path, **kw: object) -> list[BuiltPlanner]:
    return build_planners(["letspi-fast", "llm", "no-shield=letspi-fast"][: 2 if kw else 3],
                          options(srv.spec(), bank, **kw))


def test_llm_planners_plan_a_batch_as_they_plan_each_scenario_alone(llm_setup: tuple[LlmTestServer, Path]) -> None:
    srv, bank = llm_setup
    batch = scenarios(10, seed=1).history()
    shielded = 0.0
    for built in _llm_planners(srv, bank):
        planner = built.planner
        assert isinstance(planner, ProposingPlanner) and planner.proposes_per_scenario
        batched = planner.plan(batch)
        _assert_same_plans(batched, _per_scenario(planner, batch))
        shielded += float(np.nansum(batched.info["shielded"]))
    assert shielded > 0  # the shield replaced some plans: the batched shield path ran


def test_physics_planners_plan_a_batch_as_they_plan_each_scenario_alone() -> None:
    batch = scenarios(12, seed=2).history()
    for built in build_planners(["sf", "sf-opt", "gnp"], PlannerOptions()):
        planner = built.planner
        assert isinstance(planner, ProposingPlanner) and not planner.proposes_per_scenario
        _assert_same_plans(planner.plan(batch), _per_scenario(planner, batch))


def test_a_scenario_plan_does_not_depend_on_the_other_proposals_of_its_batch(
        llm_setup: tuple[LlmTestServer, Path]) -> None:
    """Bit for bit: simulate over a subset of a pool of proposals gives that subset's rows of the whole
    pool's plans (what lets the harness pool proposals in any part without changing results)."""
    srv, bank = llm_setup
    batch = scenarios(10, seed=3).history()
    rng = np.random.default_rng(0)
    for built in [*_llm_planners(srv, bank), *build_planners(["sf-opt"], PlannerOptions(goals="kinematic"))]:
        planner = built.planner
        assert isinstance(planner, ProposingPlanner)
        context = planner.context(batch)
        proposals = planner.propose(batch, context)
        whole = planner.simulate(batch, context, proposals)
        for size in (1, 3, 7):
            idx = np.sort(rng.choice(len(batch), size=size, replace=False))
            part = planner.simulate(batch.take(idx), context.take(idx), proposals.take(idx))
            for name in ("xy_m", "vxy_mps", "goals_xy_m"):
                assert np.array_equal(getattr(part, name), getattr(whole, name)[idx]), (built.name, name)
            for key, values in part.info.items():
                same = np.array_equal(values, np.asarray(whole.info[key])[idx], equal_nan=True)
                assert key in TIMING_INFO or same, (built.name, key)


def test_proposals_are_the_decision_and_simulate_follows_them(llm_setup: tuple[LlmTestServer, Path]) -> None:
    """Swapping two scenarios' proposals swaps what is simulated: the plan follows the proposal."""
    srv, bank = llm_setup
    planner = _llm_planners(srv, bank, shield=False)[0].planner
    assert isinstance(planner, ProposingPlanner)
    batch = scenarios(2, seed=4).history()
    context = planner.context(batch)
    proposals = planner.propose(batch, context)
    assert len(proposals) == 2 and proposals.info["llm_calls"].tolist() == [1.0, 1.0]
    assert not np.array_equal(proposals.params.as_matrix()[0], proposals.params.as_matrix()[1])
    swapped = Proposals.concat([proposals.take([1]), proposals.take([0])])
    plan = planner.simulate(batch, context, swapped)
    params = plan.info["k_np"]  # info follows the proposal too
    np.testing.assert_array_equal(params, proposals.info["k_np"][::-1])
    own = planner.simulate(batch, context, proposals)
    assert not np.allclose(plan.xy_m[0], own.xy_m[0])


def test_evaluate_pools_proposals_per_part_and_stores_the_per_scenario_results(
        llm_setup: tuple[LlmTestServer, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Parts of 64 with contexts in blocks of 64 (the default) and 4 in flight store exactly what parts
    of one scenario with contexts of one scenario (per-scenario physics, in sequence) store."""
    srv, bank = llm_setup
    batch = scenarios(14, seed=6)
    evaluate(_llm_planners(srv, bank), batch, tmp_path / "pooled", EvaluationSettings(concurrency=4))
    monkeypatch.setattr(concurrent, "PART_SCENARIOS", 1)
    monkeypatch.setattr(concurrent, "CONTEXT_BLOCK", 1)
    evaluate(_llm_planners(srv, bank), batch, tmp_path / "single", EvaluationSettings(concurrency=1))
    for name in ("letspi-fast", "llm", "no-shield"):
        pooled, single = stored_results(tmp_path / "pooled", name), stored_results(tmp_path / "single", name)
        assert len(pooled) == 14
        pd.testing.assert_frame_equal(pooled, single)


def test_block_cache_computes_each_block_once_for_fixed_positions() -> None:
    calls: list[slice] = []
    lock = threading.Lock()

    def compute(rows: slice) -> list[int]:
        with lock:
            calls.append(rows)
        return list(range(rows.start, rows.stop))

    cache: BlockCache[list[int]] = BlockCache(4, 10, compute)
    results: dict[int, int] = {}

    def ask(i: int) -> None:
        value, offset, _ = cache.get(i)
        results[i] = value[offset]

    threads = [threading.Thread(target=ask, args=(i,)) for i in (9, 3, 0, 5, 8, 1, 2, 4, 6, 7) * 3]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert results == {i: i for i in range(10)}  # each position gets its own row of its block
    assert sorted((s.start, s.stop) for s in calls) == [(0, 4), (4, 8), (8, 10)]  # once per block, last one short
    cache.discard_below(8)
    cache.get(9)
    assert len(calls) == 3  # block 2 was kept
    cache.get(1)
    assert len(calls) == 4  # block 0 was forgotten: computed again
