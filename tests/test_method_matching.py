"""Scenario matching: the fixed similarity formula, top-k ordering and tie-breaking."""

from __future__ import annotations

import numpy as np

from letspi.method.matching import PAPER_WEIGHTS, paper_literal_similarities, similarities, top_k
from letspi.scenario.features import FEATURE_NAMES

# n_vehicles, ego_speed, lane_change, min_dist, mean_dist, mean_nbr_speed
QUERY = np.array([[4.0, 30.0, 0.0, 20.0, 40.0, 28.0]])
MEMORY = np.array([
    [8.0, 15.0, 1.0, 80.0, 90.0, 10.0],   # 0: very different
    [4.0, 30.0, 0.0, 20.0, 40.0, 28.0],   # 1: identical
    [4.0, 31.0, 0.0, 22.0, 41.0, 28.0],   # 2: close
    [5.0, 27.0, 0.0, 30.0, 50.0, 25.0],   # 3: further
    [4.0, 30.0, 1.0, 20.0, 40.0, 28.0],   # 4: identical except lane change
])


def test_weights_follow_feature_names() -> None:
    assert len(PAPER_WEIGHTS) == len(FEATURE_NAMES) == 6


def test_fixed_formula_by_hand() -> None:
    sim = similarities(QUERY, MEMORY)
    assert sim.shape == (1, 5)
    assert sim[0, 1] == 1.0
    d2 = 2.0 * (1 / 30) + 2.5 * (2 / 20) + 1.5 * (1 / 40)
    np.testing.assert_allclose(sim[0, 2], 1 / (1 + d2))
    # binary lane_change mismatch with f_curr = 0: |1| / eps clipped to 1 -> the full weight 3
    np.testing.assert_allclose(sim[0, 4], 1 / (1 + 3.0))


def test_top_k_most_similar_first_and_paper_literal_reverses() -> None:
    idx, sims = top_k(QUERY, MEMORY, 3)
    assert idx.tolist() == [[1, 2, 3]]
    assert np.all(np.diff(sims, axis=1) <= 0) and sims[0, 0] == 1.0
    full = np.argsort(-similarities(QUERY, MEMORY)[0], kind="stable")
    literal = np.argsort(-paper_literal_similarities(QUERY, MEMORY)[0], kind="stable")
    assert full[0] == 1 and full[-1] == 0
    # the printed formula ranks the most different memory first and the identical one last
    assert literal[0] == 0 and literal[-1] == 1


def test_ties_break_by_index_across_the_partition_boundary() -> None:
    mem = np.repeat(MEMORY[[2]], 7, axis=0)
    mem[3] = QUERY[0]
    idx, sims = top_k(QUERY, mem, 3)
    assert idx.tolist() == [[3, 0, 1]]
    assert sims[0, 0] == 1.0 and sims[0, 1] == sims[0, 2]


def test_batch_matches_single_queries_and_brute_force() -> None:
    rng = np.random.default_rng(3)
    mem = rng.uniform(0, 50, (2000, 6))
    mem[:, 2] = rng.random(2000) < 0.2
    q = mem[rng.choice(2000, 17)] + rng.normal(0, 0.5, (17, 6))
    idx, sims = top_k(q, mem, 10)
    full = similarities(q, mem)
    for i in range(len(q)):
        brute = np.lexsort((np.arange(2000), -full[i]))[:10]
        assert idx[i].tolist() == brute.tolist()
        np.testing.assert_allclose(sims[i], full[i, brute])
        one_idx, _ = top_k(q[i], mem, 10)
        assert one_idx[0].tolist() == idx[i].tolist()


def test_edge_cases() -> None:
    assert top_k(QUERY, MEMORY, 0)[0].shape == (1, 0)
    assert top_k(QUERY, MEMORY, 99)[0].shape == (1, 5)
    assert top_k(QUERY, np.zeros((0, 6)), 3)[0].shape == (1, 0)
    nan_mem = MEMORY.copy()
    nan_mem[1, 0] = np.nan
    idx, sims = top_k(QUERY, nan_mem, 5)
    assert idx[0, -1] == 1 and sims[0, -1] == 0.0
