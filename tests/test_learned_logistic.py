"""Logistic regression with NumPy inference (``letspi.learned.logistic``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from letspi.learned.logistic import LogisticModel
from letspi.learned.logistic_fit import fit_logistic, roc_auc


def test_roc_auc_by_hand_with_ties_and_one_class() -> None:
    assert roc_auc(np.array([0.1, 0.4, 0.35, 0.8]), np.array([0, 0, 1, 1], bool)) == pytest.approx(0.75)
    assert roc_auc(np.array([1.0, 1.0, 1.0]), np.array([0, 1, 0], bool)) == pytest.approx(0.5)
    assert roc_auc(np.array([3.0, 2.0, 1.0]), np.array([1, 1, 0], bool)) == 1.0
    assert np.isnan(roc_auc(np.array([1.0, 2.0]), np.array([0, 0], bool)))


def test_a_known_binary_model_is_recovered() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(20000, 2)) * [2.0, 1.0] + [1.0, -1.0]
    logit = 1.5 * x[:, 0] - 2.0 * x[:, 1] + 0.5
    y = (rng.random(len(x)) < 1 / (1 + np.exp(-logit))).astype(int)
    m = fit_logistic(x, y, classes=("no", "yes"), feature_names=("a", "b"), l2=1e-6)
    # class-1 minus class-0 weights in the raw units: (w1 - w0) / std
    w = (m.weights[:, 1] - m.weights[:, 0]) / m.std
    assert w == pytest.approx([1.5, -2.0], rel=0.05)
    p = m.score(np.array([[0.0, 0.0]]))[0]
    assert p == pytest.approx(1 / (1 + np.exp(-0.5)), abs=0.03)
    assert roc_auc(m.score(x), y.astype(bool)) > 0.85


def test_multinomial_classes_sample_weights_and_json_round_trip(tmp_path) -> None:  # type: ignore[no-untyped-def]
    x = np.array([[0.0], [1.0], [2.0], [3.0], [4.0], [5.0]])
    y = np.array([0, 0, 1, 1, 2, 2])
    m = fit_logistic(x, y, classes=("a", "b", "c"), feature_names=("f",), l2=1e-3, provenance={"seed": 7})
    assert m.predict(x).tolist() == y.tolist()
    assert m.probabilities(x).sum(axis=1) == pytest.approx(np.ones(6))
    # weight on the middle class's points only: everything becomes "b"
    w = np.array([0.0, 0.0, 1.0, 1.0, 0.0, 0.0])
    assert (fit_logistic(x, y, classes=("a", "b", "c"), feature_names=("f",), sample_weight=w).predict(x) == 1).all()
    path = tmp_path / "m.json"
    path.write_text(json.dumps(m.to_json()))
    back = LogisticModel.load(path)
    np.testing.assert_array_equal(back.probabilities(x), m.probabilities(x))
    assert back.provenance["seed"] == 7 and back.classes == ("a", "b", "c")
    path.write_text(json.dumps({"format": "something else"}))
    with pytest.raises(ValueError, match="m.json: format"):
        LogisticModel.load(path)
