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
from letspi.learned.train.gnp_train import GnpTrainConfig, train_gnp_model
from letspi.learned.train.goal_train import GoalTrainConfig, train_goal_model

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
