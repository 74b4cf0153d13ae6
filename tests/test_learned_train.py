"""Training on a tiny set: the loss goes down and a seed reproduces the weights exactly."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_learned_scenes import random_batch

from letspi.learned.layers import EncoderConfig
from letspi.physics.goals import KinematicGoalPredictor
from letspi.physics.params import SocialForceParams

pytest.importorskip("torch")
pytest.importorskip("letspi_train", reason="letspi-train is not installed (pip install -e packages/letspi-train)")
from letspi_train.learned.gnp_train import GnpTrainConfig, train_gnp_model
from letspi_train.learned.goal_train import GoalTrainConfig, train_goal_model

TINY = EncoderConfig(d_model=16, n_heads=2, n_layers=1, d_ff=32)


def _tiny_batch(n: int = 48):  # type: ignore[no-untyped-def]
    batch = random_batch(np.random.default_rng(4), n)
    return replace(batch, ego_id=np.arange(n, dtype=np.int32))  # one window per vehicle


def test_goal_training_reduces_loss_and_is_deterministic() -> None:
    batch = _tiny_batch()
    cfg = GoalTrainConfig(epochs=8, batch_size=16, lr=3e-3, n_goals=3, encoder=TINY, val_fraction=0.25, seed=5)
    a = train_goal_model(batch, cfg)
    b = train_goal_model(batch, cfg)
    assert a.train_loss[-1] < 0.8 * a.train_loss[0]
    assert a.train_loss == b.train_loss
    for k in a.arrays:
        np.testing.assert_array_equal(a.arrays[k], b.arrays[k])
    c = train_goal_model(batch, replace(cfg, seed=6))
    assert any(not np.array_equal(a.arrays[k], c.arrays[k]) for k in a.arrays)
    assert set(a.manifest["validation"]) >= {"learned", "kinematic"}


@pytest.mark.slow  # 15 s on a loaded 2-core machine (notes/reliability.md)
def test_gnp_training_reduces_loss_and_is_deterministic() -> None:
    batch = _tiny_batch(40)
    cfg = GnpTrainConfig(epochs=4, batch_size=16, lr=1e-2, encoder=TINY, val_fraction=0.25, seed=2,
                         max_train=None, max_val=None)
    base = SocialForceParams(tau_s=2.5)  # deliberately poor start so there is something to learn
    a = train_gnp_model(batch, cfg, base, KinematicGoalPredictor())
    b = train_gnp_model(batch, cfg, base, KinematicGoalPredictor())
    assert a.train_loss[-1] < a.train_loss[0]
    assert a.train_loss == b.train_loss
    for k in a.arrays:
        np.testing.assert_array_equal(a.arrays[k], b.arrays[k])
    val = a.manifest["validation"]
    assert {"gnp", "sf"} <= set(val) and np.isfinite(val["gnp"]["ade_m"])
    with pytest.raises(ValueError):
        train_gnp_model(batch, replace(cfg, neighbour_mode="ground_truth_oracle"), base, KinematicGoalPredictor())


def test_train_steps_clips_each_update_and_reports_every_step() -> None:
    """With SGD at lr 1, a clipped step moves the parameters by exactly the clip norm, whatever the loss scale."""
    import torch

    from letspi_train.learned.loop import BestState, shuffled_batches, train_steps

    model = torch.nn.Linear(3, 1, bias=False)
    with torch.no_grad():
        model.weight.zero_()
    opt = torch.optim.SGD(model.parameters(), lr=1.0)
    x = torch.ones(8, 3)
    seen: list[tuple[int, float]] = []
    before = model.weight.detach().clone()
    losses = train_steps(model, opt, [slice(0, 4)], lambda s: 1e6 * (model(x[s]) - 1.0).pow(2).mean(),
                         clip_norm=0.5, on_step=lambda k, loss: seen.append((k, loss)))
    assert losses == [1e6] and seen == [(1, 1e6)]
    assert float((model.weight.detach() - before).norm()) == pytest.approx(0.5)
    batches = shuffled_batches(10, 4, torch.Generator().manual_seed(0))
    assert [len(b) for b in batches] == [4, 4, 2] and sorted(torch.cat(batches).tolist()) == list(range(10))
    best = BestState(model)
    kept = model.weight.detach().clone()
    best.offer(model, 2.0)
    with torch.no_grad():
        model.weight.add_(1.0)
    best.offer(model, 3.0)  # worse: not kept
    best.restore(model)
    assert best.val_loss == 2.0 and torch.equal(model.weight, kept)
