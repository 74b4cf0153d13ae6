"""Training pieces of the decision step: exported trees, preset selection and decision-focused labels."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from letspi.analysis.options import OptionOutcomes
from letspi.learned.trees import TreeEnsemble
from letspi.method.decide import DEFAULT_NAME, OptionTable
from letspi.physics.params import SocialForceParams

pytest.importorskip("letspi_train", reason="letspi-train is not installed (pip install -e packages/letspi-train)")
from letspi_train.finetune.decide_data import (
    ChoiceLabel,
    choice_labels,
    label_frame,
    pool_option_table,
    select_presets,
)


def _outcomes(collision, predicted_safe=None, adverse=None, success=None):  # type: ignore[no-untyped-def]
    c = np.array(collision, bool)
    b, k = c.shape
    return OptionOutcomes(
        collision=c, at_fault=c.copy(), success=np.array(success, bool) if success is not None else ~c,
        min_ttc_s=np.full((b, k), np.inf), progress_m=np.tile(100.0 - 5 * np.arange(k), (b, 1)),
        predicted_safe=np.array(predicted_safe, bool) if predicted_safe is not None else np.ones((b, k), bool),
        adverse_failed=np.array(adverse, bool) if adverse is not None else np.zeros((b, k, 1), bool),
        adverse_applies=np.zeros((b, 1), bool))


def test_exported_trees_score_as_scikit_learn_and_round_trip(tmp_path: Path) -> None:
    pytest.importorskip("sklearn")
    from letspi_train.finetune.gate_train import fit_trees

    rng = np.random.default_rng(1)
    x = rng.normal(size=(800, 3))
    x[::13, 1] = np.nan  # missing values take their learned side
    y = x[:, 0] + np.nan_to_num(x[:, 1]) > 0.5
    model = fit_trees(x, y, feature_names=("a", "b", "c"), max_iter=30)  # raises if the export disagrees
    path = tmp_path / "t.json"
    path.write_text(json.dumps(model.to_json()))
    back = TreeEnsemble.load(path)
    np.testing.assert_array_equal(back.score(x), model.score(x))
    assert back.score(x)[y].mean() > back.score(x)[~y].mean() + 0.3
    with pytest.raises(ValueError, match=r"\(B, 3\)"):
        back.score(x[:, :2])


def test_presets_cover_the_windows_where_the_defaults_collide_with_options_that_pass_the_checks() -> None:
    # 4 windows; the defaults collide in 0-2. Option 1 fixes 0 and 1 but fails a check in 1; option 2 fixes
    # 1 and 2 and passes; option 3 fixes 0 only.
    o = _outcomes(collision=[[1, 0, 1, 0], [1, 0, 0, 1], [1, 1, 0, 1], [0, 0, 0, 0]],
                  predicted_safe=[[1, 1, 1, 1], [1, 0, 1, 1], [1, 1, 1, 1], [1, 1, 1, 1]])
    assert select_presets(o, 3) == [0, 2, 1]  # 2 makes two windows fixable, then 1 (or 3) the last one
    assert select_presets(o, 1) == [0]


def test_labels_take_the_best_expected_utility_where_the_gate_consults() -> None:
    o = _outcomes(collision=[[1, 0, 0], [0, 0, 0], [0, 0, 0]], adverse=[[[1], [1], [0]], [[0], [0], [0]],
                                                                          [[0], [0], [0]]])
    eu = np.array([[0.0, 0.5, 0.2], [0.0, -0.1, -0.2], [0.0, 0.3, 0.1]])
    consulted = np.array([True, True, False])
    labels = choice_labels(eu, np.array([0.3, 0.2, 0.01]), consulted, o, keep_share=1.0, refine_weight=2.0)
    assert labels[:2] == [ChoiceLabel(0, 1, 1.0, 0.3), ChoiceLabel(0, 2, 2.0, 0.3, rejected=1)]
    assert labels[2] == ChoiceLabel(1, 0, 1.0, 0.2)  # nothing beats the defaults
    assert labels[3] == ChoiceLabel(2, 0, 1.0, 0.01)  # not consulted: a keep example
    table = OptionTable((DEFAULT_NAME, "a", "b"), np.zeros((3, 8)))
    frame = label_frame(labels, o, table, ["leader-brakes"], ["d0", "d1", "d2"])
    assert list(frame["kind"]) == ["propose", "refine", "propose", "propose"]
    assert list(frame["option"]) == ["a", "b", "default", "default"] and frame["rejected"][1] == "a"
    assert json.loads(frame["lines_json"][0]) == [["default", ["leader-brakes"], 100.0], ["a", ["leader-brakes"], 95.0],
                                                  ["b", [], 90.0]]


def test_the_pool_starts_with_the_defaults_and_names_each_option_once() -> None:
    pool = pool_option_table(SocialForceParams())
    assert pool.names[0] == DEFAULT_NAME and len(set(pool.names)) == len(pool) == 26
    assert pool.values_of("slow")["lon_factor"] == 0.7 and pool.values_of("right-brake")["lane_factor"] == 1.0
    assert pool.values_of("ease-gap")["k_np"] == 35.0
