"""Training the risk gate's trees (scikit-learn's histogram gradient boosting; the ``train`` extra), exported to
``letspi.learned.trees.TreeEnsemble``; ``fit_trees`` raises unless the export scores as scikit-learn does (1e-9).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from letspi.learned.trees import Tree, TreeEnsemble


def fit_trees(x: np.ndarray, y: np.ndarray, *, feature_names: tuple[str, ...], max_iter: int = 150,
              learning_rate: float = 0.05, max_leaf_nodes: int = 15, min_samples_leaf: int = 40, seed: int = 0,
              sample_weight: np.ndarray | None = None, provenance: dict[str, Any] | None = None) -> TreeEnsemble:
    """A binary gradient-boosted classifier of ``y`` (B,) bool from ``x`` (B, D), exported."""
    from sklearn.ensemble import HistGradientBoostingClassifier

    xs = np.asarray(x, dtype=np.float64)
    clf = HistGradientBoostingClassifier(max_iter=max_iter, learning_rate=learning_rate,
                                         max_leaf_nodes=max_leaf_nodes, min_samples_leaf=min_samples_leaf,
                                         early_stopping=False, random_state=seed)
    clf.fit(xs, np.asarray(y, dtype=np.int64), sample_weight=sample_weight)
    if list(clf.classes_) != [0, 1]:
        raise ValueError(f"the gate needs both classes in its training data, got {list(clf.classes_)}")
    trees = []
    for (predictor,) in clf._predictors:  # one tree per iteration for a binary classifier
        nodes = predictor.nodes
        leaf = nodes["is_leaf"].astype(bool)
        trees.append(Tree(feature=np.where(leaf, -1, nodes["feature_idx"]).astype(np.int64),
                          threshold=nodes["num_threshold"].astype(np.float64),
                          missing_left=nodes["missing_go_to_left"].astype(bool),
                          left=nodes["left"].astype(np.int64), right=nodes["right"].astype(np.int64),
                          value=np.where(leaf, nodes["value"], 0.0).astype(np.float64)))
    baseline = float(np.asarray(clf._baseline_prediction).ravel()[0])
    settings = {"max_iter": max_iter, "learning_rate": learning_rate, "max_leaf_nodes": max_leaf_nodes,
                "min_samples_leaf": min_samples_leaf, "seed": seed}
    model = TreeEnsemble(feature_names, baseline, tuple(trees), {**(provenance or {}), "trees": settings})
    reference = clf.predict_proba(xs)[:, 1]
    gap = float(np.max(np.abs(model.score(xs) - reference))) if len(xs) else 0.0
    if gap > 1e-9:
        raise RuntimeError(f"the exported trees disagree with scikit-learn by {gap:.2e} on the training inputs")
    return model
