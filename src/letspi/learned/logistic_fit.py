"""Fitting the logistic models of ``letspi.learned.logistic`` (SciPy's L-BFGS; deterministic), and the ROC AUC
they are judged by."""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import minimize
from scipy.stats import rankdata

from letspi.learned.logistic import LogisticModel


def fit_logistic(
    x: np.ndarray,
    y: np.ndarray,
    *,
    classes: tuple[str, ...],
    feature_names: tuple[str, ...],
    l2: float = 1.0,
    sample_weight: np.ndarray | None = None,
    provenance: dict[str, Any] | None = None,
) -> LogisticModel:
    """Fit on inputs (B, D) and class indices y (B,) in ``range(len(classes))``, minimising the sample-weighted
    cross-entropy plus ``l2 * |W|^2 / 2`` per unit of total sample weight; a constant feature gets std 1."""
    xs = np.asarray(x, dtype=np.float64)
    yi = np.asarray(y, dtype=np.int64)
    b, d = xs.shape
    k = len(classes)
    if len(yi) != b or yi.min(initial=0) < 0 or yi.max(initial=0) >= k:
        raise ValueError(f"labels must be {b} class indices in 0..{k - 1}")
    w = np.ones(b) if sample_weight is None else np.asarray(sample_weight, dtype=np.float64)
    w = w / w.sum()
    mean = xs.mean(axis=0)
    std = xs.std(axis=0)
    std = np.where(std > 1e-12, std, 1.0)
    z = (xs - mean) / std
    onehot = np.eye(k)[yi]

    def loss(theta: np.ndarray) -> tuple[float, np.ndarray]:
        wm, bias = theta[: d * k].reshape(d, k), theta[d * k:]
        logits = z @ wm + bias
        logits = logits - logits.max(axis=1, keepdims=True)
        logp = logits - np.log(np.exp(logits).sum(axis=1, keepdims=True))
        value = -(w[:, None] * onehot * logp).sum() + 0.5 * l2 * (wm**2).sum()
        resid = w[:, None] * (np.exp(logp) - onehot)  # (B, K)
        grad = np.concatenate([(z.T @ resid + l2 * wm).ravel(), resid.sum(axis=0)])
        return float(value), grad

    res = minimize(loss, np.zeros(d * k + k), jac=True, method="L-BFGS-B", options={"maxiter": 2000})
    theta = res.x
    return LogisticModel(feature_names, classes, mean, std, theta[: d * k].reshape(d, k), theta[d * k:],
                         {**(provenance or {}), "l2": l2, "n_samples": b, "converged": bool(res.success)})


def roc_auc(score: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve of ``score`` for the boolean ``positive`` (ties count half); NaN when one
    class is absent."""
    s = np.asarray(score, dtype=np.float64)
    pos = np.asarray(positive, dtype=bool)
    n_pos, n_neg = int(pos.sum()), int((~pos).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    ranks = rankdata(s)  # ties get their average rank (Mann-Whitney U)
    return float((ranks[pos].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))
