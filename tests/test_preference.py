"""The preference step's pieces (pairs ranked in hindsight, the DPO loss) and the rebalanced supervised split."""

from __future__ import annotations

import math

import numpy as np
import pytest

from letspi.finetune.data import ChatExample
from letspi.finetune.preference import dpo_loss, hindsight_utility, ranked_pairs
from letspi.finetune.train import rebalance

W = {"at_fault": 8.0, "contact": 2.0, "progress_per_m": 0.01}
NAMES = ("default", "ease", "slow", "brake")


def test_the_best_preset_in_hindsight_is_preferred_to_each_one_whose_outcome_is_worse() -> None:
    # [at_fault, contact, success, progress_m]: the defaults collide at fault; ease avoids it and succeeds;
    # slow avoids it but misses the endpoint; brake the same with less progress
    h = np.array([[1, 1, 1, 120.0], [0, 0, 1, 110.0], [0, 0, 0, 100.0], [0, 0, 0, 80.0]])
    u = hindsight_utility(h, W)
    np.testing.assert_allclose(u, [-8 - 2 + 1, 1 - 0.1, -0.2, -0.4])
    assert ranked_pairs(NAMES, h, W, margin=1.0) == [("ease", "default"), ("ease", "slow"), ("ease", "brake")]
    assert ranked_pairs(NAMES, h, W, margin=2.0) == [("ease", "default")]
    calm = np.array([[0, 0, 1, 120.0], [0, 0, 1, 110.0], [0, 0, 1, 100.0], [0, 0, 1, 80.0]])
    assert ranked_pairs(NAMES, calm, W, margin=1.0) == []  # progress alone makes no pair


def test_the_dpo_loss_is_the_log_sigmoid_of_the_scaled_margin_over_the_reference() -> None:
    torch = pytest.importorskip("torch")
    pc, pr = torch.tensor([-1.0, -2.0]), torch.tensor([-3.0, -1.0])
    rc, rr = torch.tensor([-2.0, -2.0]), torch.tensor([-2.0, -2.0])
    # margins: (1 - (-1)) = 2 and (0 - 1) = -1; beta 0.5 -> 1.0 and -0.5
    expected = (math.log1p(math.exp(-1.0)) + math.log1p(math.exp(0.5))) / 2
    assert float(dpo_loss(pc, pr, rc, rr, 0.5)) == pytest.approx(expected, rel=1e-6)
    same = dpo_loss(rc, rr, rc, rr, 0.1)  # the policy equals the reference: log 2
    assert float(same) == pytest.approx(math.log(2.0), rel=1e-6)


def test_rebalancing_repeats_the_examples_of_rare_replies() -> None:
    def ex(reply: str, i: int) -> ChatExample:
        return ChatExample((), reply, "propose", f"d{i}")

    examples = [ex("a", i) for i in range(16)] + [ex("b", 16 + i) for i in range(4)] + [ex("c", 20)]
    assert rebalance(examples, 0.0) == examples
    even = rebalance(examples, 1.0)
    counts = {r: sum(e.reply == r for e in even) for r in "abc"}
    assert counts == {"a": 16, "b": 16, "c": 8}  # 16/1 = 16 copies capped at 8
    half = rebalance(examples, 0.5)
    assert {r: sum(e.reply == r for e in half) for r in "abc"} == {"a": 16, "b": 8, "c": 4}
    assert [e.scenario_digest for e in half[16:18]] == ["d16", "d16"]  # copies stay together, in order
