"""Differentiable torch twin of ``letspi.physics.social_force`` (with per-neighbour weights).

It reproduces the NumPy rollout operation by operation, every guard and clamp included, so in float64 it
agrees with ``letspi.learned.gnp_model.rollout_weighted`` to ~1e-12 (``tests/test_learned_torch_sf.py``).
Gradients flow to every parameter and the neighbour weights; square roots are zero-safe (no NaN gradient).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from letspi.constants import DT_S
from letspi.physics.social_force import (
    AX_MAX_MPS2,
    AX_MIN_MPS2,
    AY_MAX_MPS2,
    CATCH_UP_MARGIN_MPS,
    DEFAULT_MAX_SPEED_MPS,
    EDGE_MIN_CUTOFF_M,
    EDGE_MIN_DISTANCE_M,
    LANE_LINE_SIGMA_M,
    LATERAL_RANGE_LANES,
    MAX_LATERAL_DESIRED_SPEED_MPS,
    MIN_GOAL_DISTANCE_M,
    MIN_REMAINING_TIME_S,
    SocialForceScene,
)


@dataclass(frozen=True)
class TorchScene:
    """``SocialForceScene`` as tensors (same names, shapes and layout: per-step arrays (F + 1, N, B))."""

    ego_xy0_m: torch.Tensor
    ego_vxy0_mps: torch.Tensor
    ego_length_m: torch.Tensor
    ego_width_m: torch.Tensor
    nbr_x_m: torch.Tensor
    nbr_y_m: torch.Tensor
    nbr_length_m: torch.Tensor
    nbr_width_m: torch.Tensor
    line_y_m: torch.Tensor
    line_known: torch.Tensor
    right_edge_y_m: torch.Tensor
    left_edge_y_m: torch.Tensor
    lane_width_m: torch.Tensor

    @classmethod
    def from_scene(cls, scene: SocialForceScene, dtype: torch.dtype = torch.float64) -> TorchScene:
        def t(a: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(np.ascontiguousarray(a), dtype=dtype)

        return cls(
            ego_xy0_m=t(scene.ego_xy0_m), ego_vxy0_mps=t(scene.ego_vxy0_mps), ego_length_m=t(scene.ego_length_m),
            ego_width_m=t(scene.ego_width_m), nbr_x_m=t(scene.nbr_x_m), nbr_y_m=t(scene.nbr_y_m),
            nbr_length_m=t(scene.nbr_length_m), nbr_width_m=t(scene.nbr_width_m), line_y_m=t(scene.line_y_m),
            line_known=t(scene.line_known), right_edge_y_m=t(scene.right_edge_y_m),
            left_edge_y_m=t(scene.left_edge_y_m), lane_width_m=t(scene.lane_width_m),
        )

    def __len__(self) -> int:
        return int(self.ego_xy0_m.shape[0])

    @property
    def n_steps(self) -> int:
        return int(self.nbr_x_m.shape[0]) - 1

    def take(self, idx: torch.Tensor) -> TorchScene:
        out = {}
        for name, value in vars(self).items():
            batch_last = name.startswith("nbr_") or name.startswith("line_")
            out[name] = value[..., idx] if batch_last else value[idx]
        return TorchScene(**out)


def _safe_sqrt(x: torch.Tensor) -> torch.Tensor:
    """sqrt with a zero gradient at 0 (plain sqrt gives inf * 0 = NaN there); same values."""
    pos = x > 0.0
    return torch.where(pos, torch.sqrt(torch.where(pos, x, torch.ones_like(x))), torch.zeros_like(x))


def _edge_push(side: torch.Tensor, cutoff: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    s = torch.clamp(side, min=EDGE_MIN_DISTANCE_M)
    return torch.where(s < cutoff, 1.0 / (s * s * s) - shift, torch.zeros_like(s))


def default_max_speed(scene: TorchScene, goals: torch.Tensor, dt_s: float = DT_S) -> torch.Tensor:
    """Mirror of ``letspi.physics.social_force.default_max_speed_mps`` (B,)."""
    horizon_s = max(scene.n_steps * dt_s, dt_s)
    u = torch.clamp(goals[:, 0] - scene.ego_xy0_m[:, 0], min=0.0) / horizon_s
    fastest = torch.maximum(torch.clamp(scene.ego_vxy0_mps[:, 0], min=0.0), u)
    return torch.clamp(fastest + CATCH_UP_MARGIN_MPS, max=DEFAULT_MAX_SPEED_MPS)


@dataclass(frozen=True)
class _RolloutTerms:
    """What every step of ``rollout_torch`` uses, computed once: per-scenario tensors (B,) and
    per-neighbour / per-line tensors (N, B) / (L, B)."""

    pass_speed: torch.Tensor
    inv_tau: torch.Tensor
    neg_inv_r: torch.Tensor
    max_speed: torch.Tensor
    half_len: torch.Tensor
    half_wid: torch.Tensor
    inline_dy: torch.Tensor
    lateral_dy: torch.Tensor
    line_k: torch.Tensor
    right_edge: torch.Tensor
    left_edge: torch.Tensor
    cutoff: torch.Tensor
    shift: torch.Tensor
    w_nb: torch.Tensor | None


def _rollout_terms(
    scene: TorchScene,
    params: dict[str, torch.Tensor],
    goals_xy_m: torch.Tensor,
    nbr_weights: torch.Tensor | None,
    dt_s: float,
    max_speed_mps: torch.Tensor | None,
) -> _RolloutTerms:
    lw = scene.lane_width_m
    half_wid = 0.5 * (scene.ego_width_m + scene.nbr_width_m)
    cutoff = torch.clamp(0.5 * lw - 0.5 * scene.ego_width_m, min=EDGE_MIN_CUTOFF_M)
    return _RolloutTerms(
        pass_speed=torch.clamp(goals_xy_m[:, 0] - scene.ego_xy0_m[:, 0], min=0.0) / max(scene.n_steps * dt_s, dt_s),
        inv_tau=1.0 / params["tau_s"],
        neg_inv_r=-1.0 / params["r_col_m"],
        max_speed=default_max_speed(scene, goals_xy_m, dt_s) if max_speed_mps is None else max_speed_mps,
        half_len=0.5 * (scene.ego_length_m + scene.nbr_length_m),  # (N, B)
        half_wid=half_wid,
        inline_dy=torch.maximum(0.5 * lw, half_wid),
        lateral_dy=LATERAL_RANGE_LANES * lw,
        line_k=scene.line_known * (params["k_cline"] / LANE_LINE_SIGMA_M**2),
        right_edge=scene.right_edge_y_m + 0.5 * scene.ego_width_m,
        left_edge=scene.left_edge_y_m - 0.5 * scene.ego_width_m,
        cutoff=cutoff,
        shift=1.0 / cutoff**3,
        w_nb=None if nbr_weights is None else nbr_weights.T,  # (N, B)
    )


def rollout_torch(
    scene: TorchScene,
    params: dict[str, torch.Tensor],
    goals_xy_m: torch.Tensor,
    nbr_weights: torch.Tensor | None = None,
    *,
    dt_s: float = DT_S,
    max_speed_mps: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Positions (B, F, 2) [m] and velocities (B, F, 2) [m/s] at t = dt .. F dt. ``params``: tensors (B,) keyed
    by ``PARAM_NAMES``; goals_xy_m (B, 2); nbr_weights (B, N) or None (= 1); max_speed_mps (B,) or default."""
    f = scene.n_steps
    terms = _rollout_terms(scene, params, goals_xy_m, nbr_weights, dt_s, max_speed_mps)
    ex, ey = scene.ego_xy0_m[:, 0], scene.ego_xy0_m[:, 1]
    vx, vy = scene.ego_vxy0_mps[:, 0], scene.ego_vxy0_mps[:, 1]
    xs, ys, vxs, vys = [], [], [], []
    for k in range(f):
        fgx, fgy = _goal_force(terms, goals_xy_m, ex, ey, vx, vy, remaining_s=(f - k) * dt_s)
        pre, fol, lat = _neighbour_forces(scene, terms, k, ex, ey)
        # lanes
        dm = ey - scene.line_y_m
        line = (terms.line_k * dm * torch.exp(dm * dm * (-0.5 / LANE_LINE_SIGMA_M**2))).sum(dim=0)
        edge = params["k_boundary"] * (_edge_push(ey - terms.right_edge, terms.cutoff, terms.shift)
                                       - _edge_push(terms.left_edge - ey, terms.cutoff, terms.shift))
        ax = torch.clamp(fgx + (-params["k_np"] * pre) + params["k_nf"] * fol, AX_MIN_MPS2, AX_MAX_MPS2)
        ay = torch.clamp(fgy + (-params["k_nl"] * lat) + line + edge, -AY_MAX_MPS2, AY_MAX_MPS2)
        vx = torch.clamp(vx + ax * dt_s, min=0.0)
        vy = vy + ay * dt_s
        ex = ex + vx * dt_s
        ey = ey + vy * dt_s
        xs.append(ex)
        ys.append(ey)
        vxs.append(vx)
        vys.append(vy)
    xy = torch.stack([torch.stack(xs, dim=1), torch.stack(ys, dim=1)], dim=-1)
    vxy = torch.stack([torch.stack(vxs, dim=1), torch.stack(vys, dim=1)], dim=-1)
    return xy, vxy


def _goal_force(
    terms: _RolloutTerms, goals_xy_m: torch.Tensor, ex: torch.Tensor, ey: torch.Tensor, vx: torch.Tensor,
    vy: torch.Tensor, remaining_s: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Goal attraction (x, y) (B,) with ``remaining_s`` left (the pass-through goal over the last second)."""
    overrun = max(MIN_REMAINING_TIME_S - remaining_s, 0.0)
    gx = goals_xy_m[:, 0] + terms.pass_speed * overrun - ex
    gy = goals_xy_m[:, 1] - ey
    dist = torch.clamp(_safe_sqrt(gx * gx + gy * gy), min=MIN_GOAL_DISTANCE_M)
    v0 = torch.minimum(dist / max(remaining_s, MIN_REMAINING_TIME_S), terms.max_speed)
    scale = v0 / dist
    vdx = torch.clamp(scale * gx, min=0.0)
    vdy = torch.clamp(scale * gy, -MAX_LATERAL_DESIRED_SPEED_MPS, MAX_LATERAL_DESIRED_SPEED_MPS)
    return (vdx - vx) * terms.inv_tau, (vdy - vy) * terms.inv_tau


def _neighbour_forces(
    scene: TorchScene, terms: _RolloutTerms, k: int, ex: torch.Tensor, ey: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Summed (weighted) repulsion magnitudes (B,) at step ``k`` of the in-lane neighbours ahead,
    the in-lane neighbours behind, and the lateral ones (signed by side)."""
    dx = scene.nbr_x_m[k] - ex
    dy = scene.nbr_y_m[k] - ey
    ady = torch.abs(dy)
    gap_x = torch.clamp(torch.abs(dx) - terms.half_len, min=0.0)
    gap_y = torch.clamp(ady - terms.half_wid, min=0.0)
    mag = torch.exp(_safe_sqrt(gap_x * gap_x + gap_y * gap_y) * terms.neg_inv_r)
    if terms.w_nb is not None:
        mag = mag * terms.w_nb
    inline = ady < terms.inline_dy
    lateral = (ady < terms.lateral_dy) & ~inline
    w_inline = mag * inline
    pre = (w_inline * (dx > 0.0)).sum(dim=0)
    fol = w_inline.sum(dim=0) - pre
    lat = (mag * torch.copysign(lateral.to(mag.dtype), dy)).sum(dim=0)
    return pre, fol, lat
