"""Headroom choosers on hand-made outcomes (``letspi.analysis.headroom``) and the no-model rule."""

from __future__ import annotations

import numpy as np
import pytest

from letspi.analysis.headroom import (
    best_constant,
    grouped_folds,
    headroom,
    hindsight_label,
    oracle,
    rule_over,
)
from letspi.analysis.options import OptionOutcomes
from letspi.method.decide import OptionTable, rule_choice


def _outcomes(collision: list[list[int]], success: list[list[int]], progress: list[list[float]],
              predicted_safe: list[list[int]] | None = None, adverse: list[list[list[int]]] | None = None,
              at_fault: list[list[int]] | None = None) -> OptionOutcomes:
    c = np.array(collision, bool)
    b, k = c.shape
    return OptionOutcomes(
        collision=c, at_fault=np.array(at_fault, bool) if at_fault is not None else c.copy(),
        success=np.array(success, bool), min_ttc_s=np.full((b, k), np.inf), progress_m=np.array(progress, float),
        predicted_safe=np.array(predicted_safe, bool) if predicted_safe is not None else np.ones((b, k), bool),
        adverse_failed=np.array(adverse, bool) if adverse is not None else np.zeros((b, k, 0), bool),
        adverse_applies=np.zeros((b, 0), bool))


def test_oracle_label_and_best_constant_by_hand() -> None:
    o = _outcomes(collision=[[0, 0, 1], [1, 0, 0], [1, 1, 0], [0, 1, 0]],
                  success=[[1, 1, 0], [0, 0, 1], [0, 0, 0], [0, 0, 1]],
                  progress=[[100, 120, 90], [100, 80, 95], [100, 90, 80], [100, 100, 101]])
    # window 0: defaults fine (and kept by the label) but option 1 progresses more (the oracle takes it)
    assert oracle(o, [0, 1, 2]).tolist() == [1, 2, 2, 2]
    assert hindsight_label(o, [0, 1, 2]).tolist() == [0, 2, 2, 2]
    assert oracle(o, [0, 1]).tolist() == [1, 1, 0, 0]  # window 2: both collide, the defaults progress more
    assert best_constant(o) == 2  # one contact, like option 1, but more successes


def test_rule_keeps_the_defaults_when_they_pass_and_else_takes_the_option_failing_least() -> None:
    safe = np.array([[1, 1, 1], [0, 1, 1], [1, 1, 1], [0, 0, 0]], bool)
    adverse = np.zeros((4, 3, 2), bool)
    adverse[2, 0, 0] = adverse[2, 1, 1] = True  # window 2: the defaults fail a future, option 1 too, option 2 not
    adverse[3, :, 0] = True
    adverse[3, 2, 1] = True  # window 3: everything fails; options 0 and 1 fail two checks, option 2 three
    progress = np.array([[100, 130, 90], [100, 80, 95], [100, 130, 90], [100, 120, 130.0]])
    assert rule_choice(safe, adverse, progress).tolist() == [0, 2, 2, 1]
    o = _outcomes(collision=np.zeros((4, 3)).tolist(), success=np.ones((4, 3)).tolist(), progress=progress.tolist(),
                  predicted_safe=safe.tolist(), adverse=adverse.tolist())
    assert rule_over(o, [0, 2]).tolist() == [0, 2, 2, 0]  # over a subset, indices map back
    with pytest.raises(ValueError, match="start with the defaults"):
        rule_over(o, [1, 2])


def test_grouped_folds_never_split_a_vehicle() -> None:
    groups = np.array(["a", "a", "b", "c", "c", "c", "d", "e"])
    fold = grouped_folds(groups, 3, seed=1)
    for g in np.unique(groups):
        assert len(set(fold[groups == g])) == 1
    assert set(fold) <= {0, 1, 2}


def test_headroom_table_pairs_every_chooser_with_the_defaults() -> None:
    rng = np.random.default_rng(0)
    b = 200
    collision = np.zeros((b, 3), bool)
    collision[:20, 0] = True  # the defaults collide in 20 windows; option 1 fixes 15 of them, option 2 the rest
    collision[15:20, 1] = True
    collision[40:60, 2] = True
    o = _outcomes(collision=collision.tolist(), success=(~collision).tolist(), progress=np.full((b, 3), 100.0).tolist())
    table = OptionTable(("default", "a", "b"), np.zeros((3, 8)))
    result = headroom(o, table, [0, 1, 2], rng.normal(size=(b, 20)), np.arange(b) // 2, folds=4)
    rows = {r["name"]: r for r in result.rows}
    assert rows["defaults"]["at_fault_pct"] == pytest.approx(10.0)
    assert rows["oracle, presets"]["at_fault_pct"] == 0.0
    assert rows["oracle, presets"]["vs_defaults_only_defaults"] == 20
    assert rows["oracle, presets"]["vs_defaults_p_mcnemar"] < 1e-5
    assert rows["best constant"]["at_fault_pct"] == pytest.approx(2.5)  # option 1: windows 15-19
    assert "rule: defaults unless a check fails" not in rows  # no plan-time checks in these outcomes
    assert result.n_windows == b and result.risk["n_positive"] == 20
    assert "| defaults | 10.00 [" in result.to_markdown()
