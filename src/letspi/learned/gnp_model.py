"""GNP (Goal-based Neural Physics) baseline: NumPy inference of ``letspi_train.learned.modules.GnpNet``.

From the scene encoder's tokens: a relaxation time per scenario in ``TAU_RANGE_S`` (B,) [s] and a repulsion weight
per neighbour slot in (``WEIGHT_MIN``, ``WEIGHT_MAX``) (B, N), 0 for absent neighbours; neighbour j pushes with
``w_j * k_class * exp(-d_j / r_col)`` (``sf``'s ``k_class``), so w >= 1 is never less cautious than ``sf``."""

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
    """The social force rollout with per-neighbour repulsion weights ``nbr_weights`` (B, N) (None: all 1)."""
    return rollout_social_force_scene(scene, params, goals_xy_m, dt_s=dt_s, max_speed_mps=max_speed_mps,
                                      nbr_weights=nbr_weights)
