"""``mlp``: a regressor from the six scenario-matching features to the LLM's eight answers (an ablation).

NumPy inference of the network ``letspi_train.finetune.mlp_train`` trains on the LLM's labels::

    z = (features - feat_mean) / feat_std                        (B, 6)
    h = relu(W2 relu(W1 z + b1) + b2)                            (B, H)
    values = low + (high - low) * sigmoid(W3 h + b3)             (B, 8), columns ``OUTPUT_FIELDS``
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np

from letspi.learned.layers import linear, relu
from letspi.learned.weights import WeightsError, load_weights
from letspi.physics.goals import LANE_FACTOR_RANGE, LON_FACTOR_RANGE
from letspi.physics.params import PARAM_RANGES

MODEL_NAME: Final = "param-mlp"
OUTPUT_FIELDS: Final[tuple[str, ...]] = (
    "tau_s", "k_np", "k_nf", "k_nl", "k_boundary", "k_cline", "lon_factor", "lane_factor",
)
OUTPUT_RANGES: Final[dict[str, tuple[float, float]]] = {
    **{name: PARAM_RANGES[name] for name in OUTPUT_FIELDS[:6]},
    "lon_factor": LON_FACTOR_RANGE,
    "lane_factor": LANE_FACTOR_RANGE,
}
REQUIRED: Final = ("feat_mean", "feat_std", "low", "high", "net.0.weight", "net.0.bias", "net.2.weight",
                   "net.2.bias", "net.4.weight", "net.4.bias")


def _sigmoid(x: np.ndarray) -> np.ndarray:
    out: np.ndarray = 0.5 * (1.0 + np.tanh(0.5 * x))
    return out


@dataclass(frozen=True)
class ParamMlp:
    """NumPy inference of the parameter regressor (see the module docstring)."""

    weights: dict[str, np.ndarray]
    manifest: dict[str, Any]

    @classmethod
    def from_dir(cls, model_dir: Path) -> ParamMlp:
        arrays, manifest = load_weights(model_dir, expected_model=MODEL_NAME)
        missing = [k for k in REQUIRED if k not in arrays]
        if missing:
            raise WeightsError(f"{model_dir}: weights lack {missing}")
        return cls(arrays, manifest)

    def predict(self, features: np.ndarray) -> np.ndarray:
        """features (B, 6) matching features -> (B, 8) values in ``OUTPUT_FIELDS`` order, inside the ranges."""
        w = self.weights
        x = np.nan_to_num(np.asarray(features, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
        z = (x - w["feat_mean"]) / w["feat_std"]
        h = relu(linear(w, "net.0", z))
        h = relu(linear(w, "net.2", h))
        out: np.ndarray = w["low"] + (w["high"] - w["low"]) * _sigmoid(linear(w, "net.4", h))
        return out
