"""torch mirrors of ``letspi.learned.layers`` / ``goal_model`` / ``gnp_model``; their ``state_dict`` keys are
what the NumPy side reads, so ``export_state`` output loads straight into the inference models.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from letspi.learned.features import SceneFeatures
from letspi.learned.gnp_model import TAU_RANGE_S, WEIGHT_MAX, WEIGHT_MIN
from letspi.learned.goal_model import GOAL_SCALE_X_M, GOAL_SCALE_Y_M
from letspi.learned.layers import LN_EPS, MASK_VALUE, EncoderConfig


class FeatureTensors:
    """``SceneFeatures`` as torch tensors (same shapes)."""

    def __init__(self, feats: SceneFeatures, dtype: torch.dtype = torch.float32) -> None:
        self.agent_input = torch.as_tensor(feats.agent_input(), dtype=dtype)
        self.lane = torch.as_tensor(feats.lane, dtype=dtype)
        self.agent_mask = torch.as_tensor(feats.agent_mask)
        self.anchor_xy = torch.as_tensor(feats.anchor_xy, dtype=dtype)  # (B, 2) kinematic goal [m]

    def __len__(self) -> int:
        return int(self.agent_input.shape[0])

    def take(self, idx: torch.Tensor) -> FeatureTensors:
        out = object.__new__(FeatureTensors)
        for k, v in vars(self).items():
            setattr(out, k, v[idx])
        return out


class Block(nn.Module):
    def __init__(self, cfg: EncoderConfig) -> None:
        super().__init__()
        d = cfg.d_model
        self.n_heads = cfg.n_heads
        self.ln1 = nn.LayerNorm(d, eps=LN_EPS)
        self.attn = nn.Module()
        self.attn.qkv = nn.Linear(d, 3 * d)
        self.attn.proj = nn.Linear(d, d)
        self.ln2 = nn.LayerNorm(d, eps=LN_EPS)
        self.ff1 = nn.Linear(d, cfg.d_ff)
        self.ff2 = nn.Linear(cfg.d_ff, d)

    def _attention(self, x: torch.Tensor, key_mask: torch.Tensor) -> torch.Tensor:
        b, t, d = x.shape
        h = self.n_heads
        dh = d // h
        qkv = self.attn.qkv(x).reshape(b, t, 3, h, dh).permute(2, 0, 3, 1, 4)  # type: ignore[operator]
        q, k, v = qkv[0], qkv[1], qkv[2]
        scores = q @ k.transpose(-1, -2) / math.sqrt(dh)
        bias = torch.where(key_mask, 0.0, MASK_VALUE).to(x.dtype)
        scores = scores + bias[:, None, None, :]
        p = torch.softmax(scores, dim=-1)
        out = (p @ v).permute(0, 2, 1, 3).reshape(b, t, d)
        return self.attn.proj(out)  # type: ignore[operator, no-any-return]

    def forward(self, x: torch.Tensor, key_mask: torch.Tensor) -> torch.Tensor:
        x = x + self._attention(self.ln1(x), key_mask)
        return x + self.ff2(torch.relu(self.ff1(self.ln2(x))))  # type: ignore[no-any-return]


class SceneEncoder(nn.Module):
    """Transformer over the agent tokens and a lane token (see ``letspi.learned.layers``)."""

    def __init__(self, cfg: EncoderConfig) -> None:
        super().__init__()
        d = cfg.d_model
        self.agent_in = nn.Linear(cfg.agent_input_dim, d)
        self.agent_out = nn.Linear(d, d)
        self.lane_in = nn.Linear(cfg.lane_input_dim, d)
        self.lane_out = nn.Linear(d, d)
        self.slot_embed = nn.Parameter(0.02 * torch.randn(cfg.n_agents + 1, d))
        self.blocks = nn.ModuleList([Block(cfg) for _ in range(cfg.n_layers)])
        self.ln_f = nn.LayerNorm(d, eps=LN_EPS)

    def forward(self, f: FeatureTensors) -> torch.Tensor:
        agents = self.agent_out(torch.relu(self.agent_in(f.agent_input)))
        lane = self.lane_out(torch.relu(self.lane_in(f.lane)))
        x = torch.cat([agents, lane[:, None, :]], dim=1) + self.slot_embed
        mask = torch.cat([f.agent_mask, torch.ones(len(f), 1, dtype=torch.bool)], dim=1)
        for blk in self.blocks:
            x = blk(x, mask)
        return self.ln_f(x)  # type: ignore[no-any-return]


class GoalNet(nn.Module):
    """K goals (B, K, 2) [m] and logits (B, K) from the ego token; mirrors ``LearnedGoalPredictor``."""

    def __init__(self, cfg: EncoderConfig, n_goals: int) -> None:
        super().__init__()
        self.n_goals = n_goals
        self.encoder = SceneEncoder(cfg)
        self.goal_h1 = nn.Linear(cfg.d_model, cfg.d_ff)
        self.goal_h2 = nn.Linear(cfg.d_ff, 3 * n_goals)

    def forward(self, f: FeatureTensors, horizon_s: float) -> tuple[torch.Tensor, torch.Tensor]:
        ego = self.encoder(f)[:, 0]
        out = self.goal_h2(torch.relu(self.goal_h1(ego)))
        k = self.n_goals
        off = out[:, : 2 * k].reshape(-1, k, 2)
        gx = f.anchor_xy[:, 0:1] + GOAL_SCALE_X_M * off[..., 0]
        gy = f.anchor_xy[:, 1:2] + GOAL_SCALE_Y_M * off[..., 1]
        return torch.stack([gx, gy], dim=-1), out[:, 2 * k :]


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


class GnpNet(nn.Module):
    """Per-scenario tau [s] (B,) and per-neighbour repulsion weights (B, N); mirrors ``GnpModel``. Zero-initialised
    output layers start training from the fixed-parameter model (``tau_init``, weights 1)."""

    def __init__(self, cfg: EncoderConfig, tau_init_s: float) -> None:
        super().__init__()
        self.encoder = SceneEncoder(cfg)
        self.tau_h1 = nn.Linear(cfg.d_model, cfg.d_ff)
        self.tau_h2 = nn.Linear(cfg.d_ff, 1)
        self.w_h1 = nn.Linear(cfg.d_model, cfg.d_ff)
        self.w_h2 = nn.Linear(cfg.d_ff, 1)
        lo, hi = TAU_RANGE_S
        frac = min(max((tau_init_s - lo) / (hi - lo), 0.01), 0.99)
        with torch.no_grad():
            self.tau_h2.weight.zero_()
            self.tau_h2.bias.fill_(_logit(frac))
            self.w_h2.weight.zero_()
            # start at (almost) weight 1, i.e. the sf model (the floor itself is sigmoid = 0)
            self.w_h2.bias.fill_(_logit(max((1.0 - WEIGHT_MIN) / (WEIGHT_MAX - WEIGHT_MIN), 0.02)))

    def forward(self, f: FeatureTensors) -> tuple[torch.Tensor, torch.Tensor]:
        x = self.encoder(f)
        lo, hi = TAU_RANGE_S
        tau = lo + (hi - lo) * torch.sigmoid(self.tau_h2(torch.relu(self.tau_h1(x[:, 0])))[:, 0])
        nbr = x[:, 1:-1]  # neighbour slots (the lane token is last)
        w = WEIGHT_MIN + (WEIGHT_MAX - WEIGHT_MIN) * torch.sigmoid(self.w_h2(torch.relu(self.w_h1(nbr)))[..., 0])
        return tau, w * f.agent_mask[:, 1:].to(w.dtype)


def export_state(module: nn.Module) -> dict[str, np.ndarray]:
    """The module's parameters as NumPy arrays keyed like ``state_dict``."""
    return {k: v.detach().cpu().numpy().copy() for k, v in module.state_dict().items()}
