"""The torch social force twin agrees with the NumPy rollout (float64, random scenes)."""

from __future__ import annotations

import numpy as np
import pytest
from test_learned_scenes import random_batch

from letspi.learned.gnp_model import rollout_weighted
from letspi.physics.goals import KinematicGoalPredictor
from letspi.physics.neighbours import predict_neighbours
from letspi.physics.params import PARAM_NAMES, PARAM_RANGES, SocialForceParams
from letspi.physics.social_force import SocialForceScene, rollout_social_force

torch = pytest.importorskip("torch")
pytest.importorskip("letspi_train", reason="letspi-train is not installed (pip install -e packages/letspi-train)")
from letspi_train.learned.torch_sf import TorchScene, rollout_torch  # noqa: E402


def random_params(rng: np.random.Generator, n: int) -> SocialForceParams:
    return SocialForceParams(**{k: rng.uniform(*PARAM_RANGES[k], size=n) for k in PARAM_NAMES})


def _torch_roll(scene: SocialForceScene, params: SocialForceParams, goals: np.ndarray,
                weights: np.ndarray | None) -> np.ndarray:
    tp = {k: torch.as_tensor(getattr(params, k), dtype=torch.float64) for k in PARAM_NAMES}
    w = None if weights is None else torch.as_tensor(weights, dtype=torch.float64)
    xy, _ = rollout_torch(TorchScene.from_scene(scene), tp, torch.as_tensor(goals, dtype=torch.float64), w)
    return xy.numpy()


@pytest.mark.parametrize("mode", ["idm", "constant_velocity"])
def test_torch_rollout_matches_numpy(mode: str) -> None:
    rng = np.random.default_rng(7)
    batch = random_batch(rng, 48)
    nbr = predict_neighbours(batch, mode)
    goals = KinematicGoalPredictor().predict_goals(batch).top + rng.normal(0, [15, 2], size=(len(batch), 2))
    params = random_params(rng, len(batch))
    ref = rollout_social_force(batch, params, goals, nbr)
    got = _torch_roll(SocialForceScene.from_batch(batch, nbr), params, goals, None)
    assert np.isfinite(ref.xy_m).all()
    np.testing.assert_allclose(got, ref.xy_m, rtol=0, atol=1e-9)


def test_weighted_rollouts_agree_and_reduce_to_plain_sf() -> None:
    rng = np.random.default_rng(11)
    batch = random_batch(rng, 32)
    nbr = predict_neighbours(batch, "idm")
    goals = KinematicGoalPredictor().predict_goals(batch).top
    params = random_params(rng, len(batch))
    scene = SocialForceScene.from_batch(batch, nbr)
    # weight 1 is exactly the library rollout
    plain = rollout_social_force(batch, params, goals, nbr)
    ones = rollout_weighted(scene, params, goals, np.ones((len(batch), batch.n_neighbours)))
    np.testing.assert_array_equal(ones.xy_m, plain.xy_m)
    # random weights: NumPy and torch agree
    w = rng.uniform(0.0, 4.0, size=(len(batch), batch.n_neighbours))
    ref = rollout_weighted(scene, params, goals, w)
    np.testing.assert_allclose(_torch_roll(scene, params, goals, w), ref.xy_m, rtol=0, atol=1e-9)
    # and the weights matter somewhere
    assert np.abs(ref.xy_m - plain.xy_m).max() > 1e-3


def test_torch_rollout_gradients_finite() -> None:
    rng = np.random.default_rng(3)
    batch = random_batch(rng, 8)
    nbr = predict_neighbours(batch, "idm")
    scene = TorchScene.from_scene(SocialForceScene.from_batch(batch, nbr))
    goals = torch.as_tensor(KinematicGoalPredictor().predict_goals(batch).top)
    params = {k: torch.full((len(batch),), float(np.mean(PARAM_RANGES[k])), dtype=torch.float64)
              for k in PARAM_NAMES}
    params["tau_s"].requires_grad_(True)
    w = torch.ones(len(batch), batch.n_neighbours, dtype=torch.float64, requires_grad=True)
    xy, _ = rollout_torch(scene, params, goals, w)
    xy.sum().backward()
    assert params["tau_s"].grad is not None and torch.isfinite(params["tau_s"].grad).all()
    assert w.grad is not None and torch.isfinite(w.grad).all()
