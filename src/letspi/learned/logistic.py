"""Logistic regression (binary and multinomial) with NumPy inference: the risk gate and headroom choosers.

``LogisticModel``: standardised inputs (stored training mean and std), then ``softmax(x W + b)`` over K classes
(binary: ``score`` is P(class 1)). Fitting is ``letspi.learned.logistic_fit`` (planning never loads SciPy)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

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
