"""GNP (Goal-based Neural Physics) baseline: a network sets social force parameters per scene.

``GnpModel`` (NumPy inference of ``letspi.learned.train.modules.GnpNet``) reads the scene encoder's
tokens (``letspi.learned.layers``) into

* a relaxation time per scenario, ``tau = 0.3 + 2.7 s * sigmoid(.)`` in ``TAU_RANGE_S`` (B,) [s], and
* a repulsion weight per neighbour slot, ``w_j = 1 + 3 * sigmoid(.)`` in (``WEIGHT_MIN``,
  ``WEIGHT_MAX``) = (1, 4) (B, N) [dimensionless], 0 for absent neighbours. Why the floor at the
  ``sf`` fit's strength: on calm generated traffic the trajectory loss rewards switching repulsion
  off (measured: with weights in (0, 4) they fell to 0.05 on average, with (0.5, 4) they sat at the
  floor, and in both cases the planner drove into a slower leader 40 m ahead), the same degeneracy
  ``letspi.fitting.sf`` bounds its parameters against. GNP may be more cautious than ``sf``
  per neighbour, never less.

The weight multiplies the class strength of the fixed social force model (``k_np`` / ``k_nf`` /
``k_nl`` of the shipped ``sf`` fit, stored in the GNP manifest): neighbour j pushes with
``w_j * k_class * exp(-d_j / r_col)``. GNP learns one k per neighbour in (0, 100); a multiplicative
weight keeps the class-dependent force directions of ``letspi.physics.social_force`` (a neighbour
can change class during a rollout, e.g. preceding -> lateral, and the class strengths differ by
~50x), and w = 1 everywhere is exactly the ``sf`` planner.

The planner ``gnp`` (``letspi.planners.gnp``) rolls this model out with goals from the learned goal
predictor and **predicted** neighbour motion.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np

from letspi.constants import DT_S
from letspi.learned.features import SceneFeatures
from letspi.learned.layers import EncoderConfig, encode, linear, relu
from letspi.learned.weights import WeightsError, load_weights
from letspi.physics.params import PARAM_NAMES, SocialForceParams
from letspi.physics.social_force import SocialForceScene, rollout_social_force_scene
from letspi.physics.types import RolloutResult

TAU_RANGE_S: Final = (0.3, 3.0)
WEIGHT_MIN: Final = 1.0
WEIGHT_MAX: Final = 4.0


def sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))


@dataclass(frozen=True)
class GnpModel:
    """Scene -> (tau (B,) [s], neighbour weights (B, N)); ``base_params`` are the fixed SF parameters."""

    weights: dict[str, np.ndarray]
    config: EncoderConfig
    base_params: SocialForceParams
    manifest: dict[str, Any] | None = None

    @classmethod
    def from_dir(cls, path: Path | str) -> GnpModel:
        arrays, manifest = load_weights(Path(path), expected_model="gnp")
        try:
            cfg = manifest["config"]
            enc = EncoderConfig.from_dict(cfg["encoder"])
            base = SocialForceParams.from_mapping(cfg["base_params"])
        except (KeyError, TypeError, ValueError) as exc:
            raise WeightsError(f"{path}: manifest config incomplete ({exc})") from exc
        return cls(arrays, enc, base, manifest)

    def predict(self, feats: SceneFeatures) -> tuple[np.ndarray, np.ndarray]:
        """tau (B,) [s] and per-neighbour weights (B, N) (0 for absent neighbours)."""
        w = self.weights
        x = encode(w, self.config, feats)
        lo, hi = TAU_RANGE_S
        tau = lo + (hi - lo) * sigmoid(linear(w, "tau_h2", relu(linear(w, "tau_h1", x[:, 0])))[:, 0])
        nbr = WEIGHT_MIN + (WEIGHT_MAX - WEIGHT_MIN) * sigmoid(
            linear(w, "w_h2", relu(linear(w, "w_h1", x[:, 1:-1])))[..., 0])
        return tau, nbr * feats.agent_mask[:, 1:]

    def params_batch(self, tau_s: np.ndarray) -> SocialForceParams:
        """The base parameters with the predicted tau, (B,) per field."""
        p = self.base_params.broadcast(len(tau_s))
        return SocialForceParams(**{**{n: getattr(p, n) for n in PARAM_NAMES}, "tau_s": np.asarray(tau_s)})


def rollout_weighted(
    scene: SocialForceScene,
    params: SocialForceParams,
    goals_xy_m: np.ndarray,
    nbr_weights: np.ndarray | None = None,
    *,
    dt_s: float = DT_S,
    max_speed_mps: float | np.ndarray | None = None,
) -> RolloutResult:
    """The social force rollout with per-neighbour repulsion weights ``nbr_weights`` (B, N)
    (``None``: 1 everywhere, the plain model); a thin name for GNP's use of
    ``rollout_social_force_scene(..., nbr_weights=...)``."""
    return rollout_social_force_scene(scene, params, goals_xy_m, dt_s=dt_s, max_speed_mps=max_speed_mps,
                                      nbr_weights=nbr_weights)
