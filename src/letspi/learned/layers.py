"""NumPy inference (float64) of the scene encoder shared by the goal predictor and GNP: mirrors
``letspi_train.learned.modules.SceneEncoder`` 1:1 (parameter names are its ``state_dict`` keys); tokens
(B, A + 1, d), absent neighbours masked as attention keys."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from letspi.constants import MAX_NEIGHBOURS
from letspi.learned.features import N_HIST_STEPS, N_LANE_FEATURES, N_STATIC_FEATURES, N_STEP_FEATURES, SceneFeatures

LN_EPS = 1e-5
MASK_VALUE = -1e30  # added to the scores of masked keys (finite, so no NaN when everything is masked)


@dataclass(frozen=True)
class EncoderConfig:
    """Sizes of the scene encoder (d_model must be divisible by n_heads)."""

    d_model: int = 64
    n_heads: int = 4
    n_layers: int = 2
    d_ff: int = 128
    n_agents: int = 1 + MAX_NEIGHBOURS

    @property
    def agent_input_dim(self) -> int:
        return N_HIST_STEPS * N_STEP_FEATURES + N_STATIC_FEATURES

    @property
    def lane_input_dim(self) -> int:
        return N_LANE_FEATURES

    def as_dict(self) -> dict[str, int]:
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> EncoderConfig:
        return cls(**{k: int(v) for k, v in values.items() if k in cls.__dataclass_fields__})


def linear(w: dict[str, np.ndarray], name: str, x: np.ndarray) -> np.ndarray:
    """``x @ W.T + b`` for the torch Linear called ``name``."""
    return x @ w[f"{name}.weight"].T + w[f"{name}.bias"]


def layer_norm(w: dict[str, np.ndarray], name: str, x: np.ndarray) -> np.ndarray:
    mean = x.mean(axis=-1, keepdims=True)
    var = ((x - mean) ** 2).mean(axis=-1, keepdims=True)
    return (x - mean) / np.sqrt(var + LN_EPS) * w[f"{name}.weight"] + w[f"{name}.bias"]


def relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0.0)


def attention(w: dict[str, np.ndarray], name: str, x: np.ndarray, key_mask: np.ndarray, n_heads: int) -> np.ndarray:
    """Multi-head self-attention of tokens x (B, T, d); key_mask (B, T) bool (True = attend)."""
    b, t, d = x.shape
    dh = d // n_heads
    qkv = linear(w, f"{name}.qkv", x).reshape(b, t, 3, n_heads, dh).transpose(2, 0, 3, 1, 4)
    q, k, v = qkv[0], qkv[1], qkv[2]  # (B, h, T, dh)
    scores = q @ k.transpose(0, 1, 3, 2) / np.sqrt(dh)
    scores = scores + np.where(key_mask, 0.0, MASK_VALUE)[:, None, None, :]
    scores = scores - scores.max(axis=-1, keepdims=True)
    p = np.exp(scores)
    p = p / p.sum(axis=-1, keepdims=True)
    out = (p @ v).transpose(0, 2, 1, 3).reshape(b, t, d)
    return linear(w, f"{name}.proj", out)


def encode(w: dict[str, np.ndarray], cfg: EncoderConfig, feats: SceneFeatures, prefix: str = "encoder") -> np.ndarray:
    """Encoded tokens (B, A + 1, d): agents (ego first) then the lane token."""
    p = prefix
    agents = linear(w, f"{p}.agent_out", relu(linear(w, f"{p}.agent_in", feats.agent_input())))
    lane = linear(w, f"{p}.lane_out", relu(linear(w, f"{p}.lane_in", feats.lane)))
    x = np.concatenate([agents, lane[:, None, :]], axis=1) + w[f"{p}.slot_embed"]
    mask = np.concatenate([feats.agent_mask, np.ones((len(feats), 1), dtype=bool)], axis=1)
    for i in range(cfg.n_layers):
        blk = f"{p}.blocks.{i}"
        x = x + attention(w, f"{blk}.attn", layer_norm(w, f"{blk}.ln1", x), mask, cfg.n_heads)
        x = x + linear(w, f"{blk}.ff2", relu(linear(w, f"{blk}.ff1", layer_norm(w, f"{blk}.ln2", x))))
    return layer_norm(w, f"{p}.ln_f", x)
