"""Logistic regression (binary and multinomial) with NumPy inference: the risk gate and headroom choosers.

A ``LogisticModel`` standardises its inputs (stored training mean and std), then ``softmax(x W + b)`` over
K classes (binary: ``score`` is P(class 1)). ``to_json`` / ``from_json`` round-trip it with its feature
names and provenance.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import minimize
from scipy.stats import rankdata

FORMAT = "letspi-logistic/1"


def _softmax(z: np.ndarray) -> np.ndarray:
    z = z - z.max(axis=1, keepdims=True)
    e = np.exp(z)
    out: np.ndarray = e / e.sum(axis=1, keepdims=True)
    return out


@dataclass(frozen=True)
class LogisticModel:
    """mean, std (D,): input standardisation; weights (D, K), bias (K,); classes (K,) their labels."""

    feature_names: tuple[str, ...]
    classes: tuple[str, ...]
    mean: np.ndarray
    std: np.ndarray
    weights: np.ndarray
    bias: np.ndarray
    provenance: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        d, k = len(self.feature_names), len(self.classes)
        if self.weights.shape != (d, k) or self.bias.shape != (k,) or self.mean.shape != (d,) or self.std.shape != (d,):
            raise ValueError(f"logistic model shapes do not match {d} features and {k} classes")

    def probabilities(self, x: np.ndarray) -> np.ndarray:
        """(B, K) class probabilities of inputs (B, D)."""
        xs = (np.asarray(x, dtype=np.float64) - self.mean) / self.std
        return _softmax(xs @ self.weights + self.bias)

    def score(self, x: np.ndarray) -> np.ndarray:
        """(B,) the probability of the last class (a binary model's positive class)."""
        out: np.ndarray = self.probabilities(x)[:, -1]
        return out

    def predict(self, x: np.ndarray) -> np.ndarray:
        """(B,) index of the most probable class."""
        out: np.ndarray = self.probabilities(x).argmax(axis=1)
        return out

    def to_json(self) -> dict[str, Any]:
        return {"format": FORMAT, "feature_names": list(self.feature_names), "classes": list(self.classes),
                "mean": self.mean.tolist(), "std": self.std.tolist(), "weights": self.weights.tolist(),
                "bias": self.bias.tolist(), "provenance": self.provenance}

    @classmethod
    def from_json(cls, data: dict[str, Any], source: str = "logistic model") -> LogisticModel:
        if data.get("format") != FORMAT:
            raise ValueError(f"{source}: format {data.get('format')!r}, expected {FORMAT!r}")
        try:
            return cls(tuple(data["feature_names"]), tuple(data["classes"]), np.asarray(data["mean"], dtype=np.float64),
                       np.asarray(data["std"], dtype=np.float64), np.asarray(data["weights"], dtype=np.float64),
                       np.asarray(data["bias"], dtype=np.float64), dict(data.get("provenance", {})))
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{source}: not a logistic model ({exc})") from exc

    @classmethod
    def load(cls, path: Path) -> LogisticModel:
        return cls.from_json(json.loads(Path(path).read_text()), str(path))


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
    """Fit on inputs (B, D) and class indices y (B,): weighted cross-entropy plus ``l2 * |W|^2 / 2`` per unit
    of total sample weight, by L-BFGS (deterministic). A constant feature gets std 1."""
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
    """ROC AUC of ``score`` for boolean ``positive`` (ties count half); NaN when one class is absent."""
    s = np.asarray(score, dtype=np.float64)
    pos = np.asarray(positive, dtype=bool)
    n_pos, n_neg = int(pos.sum()), int((~pos).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    ranks = rankdata(s)  # ties get their average rank (Mann-Whitney U)
    return float((ranks[pos].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))
