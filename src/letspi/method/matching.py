"""Scenario matching for the fast inference phase (paper §III-E), with the paper's similarity slip fixed.

Per feature k of ``FEATURE_NAMES``, with the paper's weights: ``d_k = min(1, |f_curr,k - f_mem,k| /
max(|f_curr,k|, eps))``, ``Sim = 1 / (1 + sum_k w_k d_k)`` in (0, 1]. The paper's ``d_k = 1 - min(...)`` is a
similarity and would rank the least similar first (``paper_literal_similarities`` keeps it). Normalised by
the current scenario, so not symmetric; NaN features give similarity 0.
"""

from __future__ import annotations

from typing import Final

import numpy as np

#: memories retrieved per scenario by the fast phase (``letspi-fast``)
TOP_K = 3

PAPER_WEIGHTS: Final = (1.0, 2.0, 3.0, 2.5, 1.5, 1.0)  # in ``FEATURE_NAMES`` order (paper §III-E)
EPS: Final = 1e-5
_CHUNK_ELEMENTS: Final = 1 << 16  # (Q-chunk x M) temporaries of ~0.5 MB stay in cache


def _check(query: np.ndarray, memory: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    w = np.asarray(weights, dtype=np.float64)
    q = np.asarray(query, dtype=np.float64)
    q = q.reshape(-1, w.shape[0]) if q.size == 0 else np.atleast_2d(q)
    m = np.asarray(memory, dtype=np.float64)
    m = m.reshape(-1, w.shape[0]) if m.size == 0 else np.atleast_2d(m)
    if q.shape[1] != w.shape[0] or m.shape[1] != w.shape[0]:
        raise ValueError(f"features must have {w.shape[0]} columns, got query {q.shape} and memory {m.shape}")
    return q, m, w


def weighted_distances(
    query: np.ndarray, memory: np.ndarray, weights: np.ndarray | tuple[float, ...] = PAPER_WEIGHTS, eps: float = EPS
) -> np.ndarray:
    """D (Q, M) = Σ_k w_k min(1, |q_k - m_k| / max(|q_k|, eps)) for query (Q, K) and memory (M, K) features;
    NaN -> +inf. Built feature by feature in a (chunk, M) buffer, never (Q, M, K)."""
    q, m, w = _check(query, memory, np.asarray(weights))
    n_q, n_m = q.shape[0], m.shape[0]
    out = np.zeros((n_q, n_m))
    if n_q == 0 or n_m == 0:
        return out
    inv_scale = 1.0 / np.maximum(np.abs(q), eps)  # (Q, K): the normalisation depends on the query only
    chunk = max(1, _CHUNK_ELEMENTS // max(n_m, 1))
    tmp = np.empty((min(chunk, n_q), n_m))
    for start in range(0, n_q, chunk):
        stop = min(start + chunk, n_q)
        acc = out[start:stop]
        buf = tmp[: stop - start]
        for k in range(q.shape[1]):
            np.subtract(q[start:stop, k, None], m[None, :, k], out=buf)
            np.abs(buf, out=buf)
            buf *= inv_scale[start:stop, k, None]
            np.minimum(buf, 1.0, out=buf)
            buf *= w[k]
            acc += buf
    out[np.isnan(out)] = np.inf
    return out


def similarities(
    query: np.ndarray, memory: np.ndarray, weights: np.ndarray | tuple[float, ...] = PAPER_WEIGHTS, eps: float = EPS
) -> np.ndarray:
    """Sim (Q, M) = 1 / (1 + D) in [0, 1] (1 = identical features); formula in the module doc."""
    return 1.0 / (1.0 + weighted_distances(query, memory, weights, eps))


def paper_literal_similarities(
    query: np.ndarray, memory: np.ndarray, weights: np.ndarray | tuple[float, ...] = PAPER_WEIGHTS, eps: float = EPS
) -> np.ndarray:
    """The paper's formula as printed, d_k = 1 - min(1, |Δf| / max(f, eps)): for comparison only (it is a slip)."""
    q, m, w = _check(query, memory, np.asarray(weights))
    ratio = np.abs(q[:, None, :] - m[None, :, :]) / np.maximum(q[:, None, :], eps)
    d = 1.0 - np.minimum(1.0, ratio)
    result: np.ndarray = 1.0 / (1.0 + (d * w).sum(axis=-1))
    return result


def top_k(query: np.ndarray, memory: np.ndarray, k: int, weights: np.ndarray | tuple[float, ...] = PAPER_WEIGHTS,
          eps: float = EPS) -> tuple[np.ndarray, np.ndarray]:
    """The k' = min(k, M) most similar memories per query: indices (Q, k') int64 and Sim (Q, k'), by descending
    similarity, ties to the lower memory index (deterministic)."""
    if k < 0:
        raise ValueError(f"k must be >= 0, got {k}")
    q, m, w = _check(query, memory, np.asarray(weights))
    n_q, n_m = q.shape[0], m.shape[0]
    kk = min(k, n_m)
    if kk == 0 or n_q == 0:
        return np.zeros((n_q, kk), dtype=np.int64), np.zeros((n_q, kk))
    # query chunks keep the (chunk, M) distance block small: a 100 x 100k block (80 MB) is memory-bound
    chunk = max(1, _CHUNK_ELEMENTS // n_m)
    parts = [_top_k_block(weighted_distances(q[i:i + chunk], m, w, eps), kk) for i in range(0, n_q, chunk)]
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def _top_k_block(dist: np.ndarray, kk: int) -> tuple[np.ndarray, np.ndarray]:
    """Top-kk of a (Q, M) distance block, 1 <= kk <= M; ordering rules of ``top_k``."""
    n_q, n_m = dist.shape
    if kk < n_m:
        idx = np.argpartition(dist, kk - 1, axis=1)[:, :kk]
    else:
        idx = np.broadcast_to(np.arange(n_m), (n_q, n_m)).copy()
    sel = np.take_along_axis(dist, idx, axis=1)
    # ties at the boundary: argpartition may pick any of several equal distances; redo those rows exactly
    kth = sel.max(axis=1)
    n_within = (dist <= kth[:, None]).sum(axis=1)
    for row in np.flatnonzero(n_within > kk):
        cand = np.flatnonzero(dist[row] <= kth[row])
        order = np.lexsort((cand, dist[row, cand]))[:kk]
        idx[row] = cand[order]
        sel[row] = dist[row, idx[row]]
    order = np.lexsort((idx, sel), axis=1)  # by distance, then index
    idx = np.take_along_axis(idx, order, axis=1).astype(np.int64)
    sel = np.take_along_axis(sel, order, axis=1)
    return idx, 1.0 / (1.0 + sel)
