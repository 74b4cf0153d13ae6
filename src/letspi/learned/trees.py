"""Gradient-boosted decision trees with NumPy inference (the risk gate; trained by
``letspi_train.finetune.gate_train``): ``sigmoid(baseline + sum of leaf values)``, all trees walked at once."""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

FORMAT = "letspi-trees/1"


@dataclass(frozen=True)
class Tree:
    """One tree, (M,) per node (``pack_trees``: (T, M)): feature (-1 at a leaf), threshold (left when ``x <=``
    it), missing_left (NaN goes left), left, right (child indices), value (the leaf's contribution)."""

    feature: np.ndarray
    threshold: np.ndarray
    missing_left: np.ndarray
    left: np.ndarray
    right: np.ndarray
    value: np.ndarray

    def predict(self, x: np.ndarray) -> np.ndarray:
        """(B,) the leaf value each row of x (B, D) reaches."""
        node = np.zeros(len(x), dtype=np.int64)
        rows = np.arange(len(x))
        for _ in range(len(self.feature)):  # at most as many levels as nodes
            inner = self.feature[node] >= 0
            if not inner.any():
                break
            f = np.where(inner, self.feature[node], 0)
            v = x[rows, f]
            go_left = np.where(np.isnan(v), self.missing_left[node], v <= self.threshold[node])
            node = np.where(inner, np.where(go_left, self.left[node], self.right[node]), node)
        out: np.ndarray = self.value[node]
        return out

    def to_json(self) -> dict[str, list[Any]]:
        return {"feature": self.feature.tolist(), "threshold": self.threshold.tolist(),
                "missing_left": self.missing_left.astype(int).tolist(), "left": self.left.tolist(),
                "right": self.right.tolist(), "value": self.value.tolist()}

    @classmethod
    def from_json(cls, d: dict[str, list[Any]]) -> Tree:
        return cls(np.asarray(d["feature"], dtype=np.int64), np.asarray(d["threshold"], dtype=np.float64),
                   np.asarray(d["missing_left"], dtype=bool), np.asarray(d["left"], dtype=np.int64),
                   np.asarray(d["right"], dtype=np.int64), np.asarray(d["value"], dtype=np.float64))


def pack_trees(trees: tuple[Tree, ...]) -> Tree:
    """T trees as one ``Tree`` of (T, M) arrays, padded with unreachable leaves of value 0."""
    m = max((len(t.feature) for t in trees), default=1)

    def pad(name: str, fill: object, dtype: type) -> np.ndarray:
        out: np.ndarray = np.full((len(trees), m), fill, dtype=dtype)
        for i, t in enumerate(trees):
            values = getattr(t, name)
            out[i, : len(values)] = values
        return out

    return Tree(pad("feature", -1, np.int64), pad("threshold", 0.0, np.float64), pad("missing_left", False, bool),
                pad("left", 0, np.int64), pad("right", 0, np.int64), pad("value", 0.0, np.float64))


def predict_packed(packed: Tree, x: np.ndarray) -> np.ndarray:
    """(T, B) the leaf value each row of x (B, D) reaches in each tree of ``packed``, as ``Tree.predict``."""
    n_trees, m = packed.feature.shape
    b, d = x.shape
    # flat indices (node of tree t: t m + node; input of row r: r d + feature) into raveled arrays
    base = (np.arange(n_trees) * m)[:, None]
    row_base = (np.arange(b) * d)[None, :]
    feature, threshold, missing_left = packed.feature.ravel(), packed.threshold.ravel(), packed.missing_left.ravel()
    left, right, flat_x = packed.left.ravel(), packed.right.ravel(), np.ascontiguousarray(x).ravel()
    at = np.broadcast_to(base, (n_trees, b)).copy()
    for _ in range(m):  # at most as many levels as nodes
        f = feature[at]
        inner = f >= 0
        if not inner.any():
            break
        v = flat_x[row_base + np.where(inner, f, 0)]
        go_left = np.where(np.isnan(v), missing_left[at], v <= threshold[at])
        at = np.where(inner, base + np.where(go_left, left[at], right[at]), at)
    out: np.ndarray = packed.value.ravel()[at]
    return out


@dataclass(frozen=True)
class TreeEnsemble:
    """A binary classifier: ``sigmoid(baseline + sum of the trees)`` over inputs named ``feature_names``."""

    feature_names: tuple[str, ...]
    baseline: float
    trees: tuple[Tree, ...]
    provenance: dict[str, Any] = field(default_factory=dict)

    def raw(self, x: np.ndarray) -> np.ndarray:
        xs = np.asarray(x, dtype=np.float64)
        if xs.ndim != 2 or xs.shape[1] != len(self.feature_names):
            raise ValueError(f"expected (B, {len(self.feature_names)}) inputs, got {xs.shape}")
        total = np.full(len(xs), self.baseline)
        for leaf_values in predict_packed(self._packed, xs):  # tree by tree, in order: Tree.predict's sum
            total += leaf_values
        return total

    @functools.cached_property
    def _packed(self) -> Tree:
        return pack_trees(self.trees)

    def score(self, x: np.ndarray) -> np.ndarray:
        """(B,) the probability of the positive class."""
        out: np.ndarray = 1.0 / (1.0 + np.exp(-self.raw(x)))
        return out

    def to_json(self) -> dict[str, Any]:
        return {"format": FORMAT, "feature_names": list(self.feature_names), "baseline": self.baseline,
                "trees": [t.to_json() for t in self.trees], "provenance": self.provenance}

    @classmethod
    def from_json(cls, data: dict[str, Any], source: str = "tree model") -> TreeEnsemble:
        if data.get("format") != FORMAT:
            raise ValueError(f"{source}: format {data.get('format')!r}, expected {FORMAT!r}")
        try:
            return cls(tuple(data["feature_names"]), float(data["baseline"]),
                       tuple(Tree.from_json(t) for t in data["trees"]), dict(data.get("provenance", {})))
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{source}: not a tree model ({exc})") from exc

    @classmethod
    def load(cls, path: Path) -> TreeEnsemble:
        return cls.from_json(json.loads(Path(path).read_text()), str(path))
