"""Batched social force rollout of the ego (paper §III-D, Eq. 2-7): unit mass, ego frame (x forward, y left).

``a = F_goal + F_neighbours + F_lane_lines + F_edges``, ``F_goal = (v0 e - v) / tau`` with v0 = |g - p| / remaining
time; a neighbour pushes with ``k_class exp(-d / r_col)``. Deviations from the paper (rationale in
notes/rationale-data-physics-metrics.md):

1. Semi-implicit Euler (``v += a dt``, then ``p += v dt``); the force at step k uses the neighbours at t = k dt.
2. ``d`` is the box-to-box distance (the bumper gap in lane, 0 when boxes overlap), not the centre distance.
3. In line (``|dy| < max(lane_width, W_e + W_j) / 2``) a neighbour pushes along x only, ahead ``-k_np``, behind
   ``+k_nf``; in an adjacent lane (``|dy| < 1.5 lane_width``) along -sign(dy) only (``k_nl``); further, not at all.
4. Lane lines are Gaussian wells of sigma = 1.22 m; road edges push inward ``k (1/d^3 - 1/d_c^3)`` from the
   ego's side, up to ``d_c = max((lane_width - W_e) / 2, 0.3 m)``.
5. Remaining time >= 1 s, below which the goal moves on at the plan's mean speed; v0 <= ``max_speed_mps``;
   ``v_des_x >= 0``, ``|v_des_y| <= 2 m/s``. Clamps: a_x in [-9, 4], |a_y| <= 3 m/s²; v_x >= 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from letspi.arrays import Batched
from letspi.constants import DT_S, T0_INDEX
from letspi.physics.lanes import lane_width_m
from letspi.physics.params import SocialForceParams, as_params_batch
from letspi.physics.types import NeighbourPrediction, RolloutResult
from letspi.scenario.types import ScenarioBatch

LANE_LINE_SIGMA_M = 1.22
MIN_REMAINING_TIME_S = 1.0
DEFAULT_MAX_SPEED_MPS = 50.0
CATCH_UP_MARGIN_MPS = 5.0
MAX_LATERAL_DESIRED_SPEED_MPS = 2.0
MIN_GOAL_DISTANCE_M = 1e-9
EDGE_MIN_DISTANCE_M = 0.1
EDGE_MIN_CUTOFF_M = 0.3
LATERAL_RANGE_LANES = 1.5
AX_MIN_MPS2 = -9.0
AX_MAX_MPS2 = 4.0
AY_MAX_MPS2 = 3.0
# Stand-in coordinate for absent things (invalid neighbour samples, padding markings, missing edges): every force
# from it underflows to exactly 0.0 for any r_col in PARAM_RANGES, so the hot loop needs no validity masks.
FAR_M = 1.0e12


def _lines_and_edges(my: np.ndarray, marking_is_edge: np.ndarray, ego_y_m: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Markings (B, M) -> crossable lines compacted to the front, (B, L) y [m] (``FAR_M`` when unknown) with known
    flags, and the right and left road edges (B,) [m] (``-FAR_M`` / ``FAR_M`` when absent); a single edge is the right
    one when it lies below the ego."""
    known = np.isfinite(my)
    is_edge = np.asarray(marking_is_edge, dtype=bool).reshape(my.shape[0], -1) & known
    is_line = known & ~is_edge
    n_lines = int(is_line.sum(axis=1).max(initial=0))
    # compact the crossable lines to the front (stable: keeps ascending order)
    order = np.argsort(~is_line, axis=1, kind="stable")[:, :n_lines]
    line_known = np.take_along_axis(is_line, order, axis=1)
    line_y = np.where(line_known, np.take_along_axis(np.where(known, my, 0.0), order, axis=1), FAR_M)
    right = np.where(is_edge, my, np.inf).min(axis=1)
    left = np.where(is_edge, my, -np.inf).max(axis=1)
    one_edge = np.isfinite(right) & (right == left)
    right_ok = np.isfinite(right) & ~(one_edge & (right > ego_y_m))
    left_ok = np.isfinite(left) & ~(one_edge & (left <= ego_y_m))
    return line_y, line_known, np.where(right_ok, right, -FAR_M), np.where(left_ok, left, FAR_M)


@dataclass(frozen=True)
class SocialForceScene(Batched):
    """Everything a rollout needs besides parameters and goals: float64, sanitised, step-major and batch-last.
    ``ego_xy0_m``, ``ego_vxy0_mps`` (B, 2) (non-finite -> 0); ``ego_length_m``, ``ego_width_m``, ``lane_width_m`` (B,);
    ``nbr_x_m``, ``nbr_y_m``, ``nbr_valid`` (F + 1, N, B), index 0 = t = 0, ``FAR_M`` where invalid; ``nbr_length_m``,
    ``nbr_width_m`` (N, B), 0 for empty slots; ``line_y_m``, ``line_known`` (L, B); ``right_edge_y_m``,
    ``left_edge_y_m`` (B,), ``-FAR_M`` / ``+FAR_M`` when absent."""

    ego_xy0_m: np.ndarray
    ego_vxy0_mps: np.ndarray
    ego_length_m: np.ndarray
    ego_width_m: np.ndarray
    nbr_x_m: np.ndarray
    nbr_y_m: np.ndarray
    nbr_valid: np.ndarray
    nbr_length_m: np.ndarray
    nbr_width_m: np.ndarray
    line_y_m: np.ndarray
    line_known: np.ndarray
    right_edge_y_m: np.ndarray
    left_edge_y_m: np.ndarray
    lane_width_m: np.ndarray

    @property
    def n_steps(self) -> int:
        return int(self.nbr_x_m.shape[0]) - 1

    @property
    def n_neighbours(self) -> int:
        return int(self.nbr_x_m.shape[1])

    def take(self, indices: np.ndarray | slice) -> SocialForceScene:
        """A sub-scene of the selected scenarios, C-contiguous as ``from_arrays`` lays it out (NumPy may round
        differently on strided arrays, and a sub-scene must roll out exactly as a scene built from it)."""
        out = {}
        for name, value in vars(self).items():
            batch_last = name.startswith("nbr_") or name.startswith("line_")
            out[name] = np.ascontiguousarray(value[..., indices] if batch_last else value[indices])
        return SocialForceScene(**out)

    @classmethod
    def from_arrays(
        cls,
        *,
        ego_xy0_m: np.ndarray,
        ego_vxy0_mps: np.ndarray,
        ego_length_m: np.ndarray,
        ego_width_m: np.ndarray,
        nbr_xy_m: np.ndarray | Sequence[np.ndarray],
        nbr_valid: np.ndarray | Sequence[np.ndarray],
        nbr_length_m: np.ndarray,
        nbr_width_m: np.ndarray,
        marking_y_m: np.ndarray,
        marking_is_edge: np.ndarray,
    ) -> SocialForceScene:
        """Build a scene from batch-first arrays. ``nbr_xy_m`` (B, N, F + 1, 2), index 0 = t = 0, or time chunks (B, N,
        F_i, 2) that concatenate to it (saves a copy); ``nbr_valid`` (B, N, F + 1) likewise; sizes (B,) / (B, N);
        ``marking_y_m`` (B, M) ascending, NaN padded. Non-finite neighbour samples become invalid, non-finite sizes and
        ego states 0."""
        ego_xy = np.nan_to_num(np.asarray(ego_xy0_m, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
        ego_v = np.nan_to_num(np.asarray(ego_vxy0_mps, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
        b = ego_xy.shape[0]
        xy_parts = [nbr_xy_m] if isinstance(nbr_xy_m, np.ndarray) else list(nbr_xy_m)
        valid_parts = [nbr_valid] if isinstance(nbr_valid, np.ndarray) else list(nbr_valid)
        nx, ny, valid_t = _step_major(xy_parts, valid_parts)

        my = np.asarray(marking_y_m, dtype=np.float64).reshape(b, -1)
        line_y, line_known, right_edge, left_edge = _lines_and_edges(my, marking_is_edge, ego_xy[:, 1])

        def size(a: np.ndarray) -> np.ndarray:
            v = np.asarray(a, dtype=np.float64)
            return np.where(np.isfinite(v) & (v > 0), v, 0.0)

        return cls(
            ego_xy0_m=ego_xy,
            ego_vxy0_mps=ego_v,
            ego_length_m=size(ego_length_m).reshape(b),
            ego_width_m=size(ego_width_m).reshape(b),
            nbr_x_m=nx,
            nbr_y_m=ny,
            nbr_valid=valid_t,
            nbr_length_m=np.ascontiguousarray(size(nbr_length_m).reshape(b, -1).T),
            nbr_width_m=np.ascontiguousarray(size(nbr_width_m).reshape(b, -1).T),
            line_y_m=np.ascontiguousarray(line_y.T),
            line_known=np.ascontiguousarray(line_known.T),
            right_edge_y_m=right_edge,
            left_edge_y_m=left_edge,
            lane_width_m=lane_width_m(my),
        )

    @classmethod
    def from_batch(cls, batch: ScenarioBatch, neighbours: NeighbourPrediction) -> SocialForceScene:
        """Ego state, sizes and markings from ``batch``; neighbours observed at t = 0 then predicted."""
        return cls.from_arrays(
            ego_xy0_m=batch.ego_xy0_m,
            ego_vxy0_mps=batch.ego_vxy0_mps,
            ego_length_m=batch.ego_length_m,
            ego_width_m=batch.ego_width_m,
            nbr_xy_m=[batch.nbr_xy_m[:, :, T0_INDEX : T0_INDEX + 1], neighbours.xy_m],
            nbr_valid=[batch.nbr_valid[:, :, T0_INDEX : T0_INDEX + 1], neighbours.valid],
            nbr_length_m=batch.nbr_length_m,
            nbr_width_m=batch.nbr_width_m,
            marking_y_m=batch.marking_y_m,
            marking_is_edge=batch.marking_is_edge,
        )


def _step_major(
    xy_parts: list[np.ndarray], valid_parts: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Time chunks (B, N, F_i, 2) / (B, N, F_i) -> x, y (F + 1, N, B) float64 and valid; invalid or non-finite samples
    get x = ``FAR_M``, y = 0."""
    b, n = xy_parts[0].shape[:2]
    total = sum(int(p.shape[2]) for p in xy_parts)
    nx = np.empty((total, n, b))
    ny = np.empty((total, n, b))
    valid = np.empty((total, n, b), dtype=bool)
    start = 0
    for xy, ok in zip(xy_parts, valid_parts, strict=True):
        stop = start + int(xy.shape[2])
        nx[start:stop] = xy[..., 0].transpose(2, 1, 0)
        ny[start:stop] = xy[..., 1].transpose(2, 1, 0)
        valid[start:stop] = np.asarray(ok, dtype=bool).transpose(2, 1, 0)
        start = stop
    valid &= np.isfinite(nx)
    valid &= np.isfinite(ny)
    invalid = ~valid
    np.copyto(nx, FAR_M, where=invalid)
    np.copyto(ny, 0.0, where=invalid)
    return nx, ny, valid


@dataclass(frozen=True)
class ForceTerms:
    """Force components at one instant, each (B, 2) [m/s²]; ``total`` their sum, ``clamped`` the acceleration applied
    (the no-reverse floor acts on the velocity and is not included)."""

    goal: np.ndarray
    preceding: np.ndarray
    following: np.ndarray
    lateral: np.ndarray
    lane_line: np.ndarray
    boundary: np.ndarray

    @property
    def neighbours(self) -> np.ndarray:
        return self.preceding + self.following + self.lateral

    @property
    def lane(self) -> np.ndarray:
        return self.lane_line + self.boundary

    @property
    def total(self) -> np.ndarray:
        return self.goal + self.neighbours + self.lane

    @property
    def clamped(self) -> np.ndarray:
        t = self.total
        return np.stack(
            [np.clip(t[:, 0], AX_MIN_MPS2, AX_MAX_MPS2), np.clip(t[:, 1], -AY_MAX_MPS2, AY_MAX_MPS2)], axis=1
        )


def _edge_push(side_m: np.ndarray, cutoff_m: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """Force-shifted inverse-cube edge push (magnitude / k_boundary) for the ego side distance."""
    s = np.maximum(side_m, EDGE_MIN_DISTANCE_M)
    return np.where(s < cutoff_m, 1.0 / (s * s * s) - shift, 0.0)


class _Kernel:
    """Per-scenario constants of the force model and the forces at one instant: ego arrays (B,), neighbours (N, B),
    lane lines (L, B)."""

    def __init__(self, scene: SocialForceScene, params: SocialForceParams, goals_xy_m: np.ndarray,
                 max_speed_mps: np.ndarray, dt_s: float, nbr_weights: np.ndarray | None = None) -> None:
        self.goal_x = np.ascontiguousarray(goals_xy_m[:, 0], dtype=np.float64)
        self.goal_y = np.ascontiguousarray(goals_xy_m[:, 1], dtype=np.float64)
        horizon_s = scene.n_steps * dt_s
        self.pass_speed = np.maximum(self.goal_x - scene.ego_xy0_m[:, 0], 0.0) / max(horizon_s, dt_s)
        self.inv_tau = 1.0 / params.tau_s
        self.k_np = params.k_np
        self.k_nf = params.k_nf
        self.k_nl = params.k_nl
        self.k_boundary = params.k_boundary
        self.neg_inv_r_col = -1.0 / params.r_col_m
        self.max_speed = max_speed_mps
        lw = scene.lane_width_m
        self.half_len = 0.5 * (scene.ego_length_m + scene.nbr_length_m)
        self.half_wid = 0.5 * (scene.ego_width_m + scene.nbr_width_m)
        self.inline_dy = np.maximum(0.5 * lw, self.half_wid)
        self.lateral_dy = LATERAL_RANGE_LANES * lw
        self.line_y = scene.line_y_m
        self.line_k = scene.line_known * (params.k_cline / LANE_LINE_SIGMA_M**2)
        self.right_edge = scene.right_edge_y_m + 0.5 * scene.ego_width_m
        self.left_edge = scene.left_edge_y_m - 0.5 * scene.ego_width_m
        cutoff = np.maximum(0.5 * lw - 0.5 * scene.ego_width_m, EDGE_MIN_CUTOFF_M)
        self.edge_cutoff = cutoff
        self.edge_shift = 1.0 / cutoff**3
        self.nbr_weights = nbr_weights  # (N, B) repulsion multipliers (GNP) or None (all 1)

    def goal_force(self, ex: np.ndarray, ey: np.ndarray, vx: np.ndarray, vy: np.ndarray,
                   remaining_s: float) -> tuple[np.ndarray, np.ndarray]:
        overrun_s = max(MIN_REMAINING_TIME_S - remaining_s, 0.0)
        gx = self.goal_x + self.pass_speed * overrun_s - ex
        gy = self.goal_y - ey
        dist = np.maximum(np.hypot(gx, gy), MIN_GOAL_DISTANCE_M)
        v0 = np.minimum(dist / max(remaining_s, MIN_REMAINING_TIME_S), self.max_speed)
        scale = v0 / dist
        vdx = np.maximum(scale * gx, 0.0)
        vdy = np.clip(scale * gy, -MAX_LATERAL_DESIRED_SPEED_MPS, MAX_LATERAL_DESIRED_SPEED_MPS)
        return (vdx - vx) * self.inv_tau, (vdy - vy) * self.inv_tau

    def neighbour_force(self, ex: np.ndarray, ey: np.ndarray, nx: np.ndarray,
                        ny: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(preceding_x, following_x, lateral_y), each (B,), from neighbours nx, ny (N, B)."""
        dx = nx - ex
        dy = ny - ey
        ady = np.abs(dy)
        gap_x = np.abs(dx)
        gap_x -= self.half_len
        np.maximum(gap_x, 0.0, out=gap_x)
        gap_y = ady - self.half_wid
        np.maximum(gap_y, 0.0, out=gap_y)
        gap_x *= gap_x
        gap_y *= gap_y
        gap_x += gap_y
        mag = np.sqrt(gap_x, out=gap_x)  # box-to-box distance, then the repulsion magnitude in place
        mag *= self.neg_inv_r_col
        np.exp(mag, out=mag)
        if self.nbr_weights is not None:
            mag *= self.nbr_weights
        inline = ady < self.inline_dy
        lateral = ady < self.lateral_dy
        lateral &= ~inline
        w_inline = mag * inline
        pre = (w_inline * (dx > 0.0)).sum(axis=0)
        fol = w_inline.sum(axis=0) - pre
        # lateral vehicles push the ego away from their side: -sign(dy)
        lat = (mag * np.copysign(lateral, dy)).sum(axis=0)
        return -self.k_np * pre, self.k_nf * fol, -self.k_nl * lat

    def lane_force(self, ey: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lane_line_y, boundary_y), each (B,)."""
        dm = ey - self.line_y
        line = (self.line_k * dm * np.exp(dm * dm * (-0.5 / LANE_LINE_SIGMA_M**2))).sum(axis=0)
        right = _edge_push(ey - self.right_edge, self.edge_cutoff, self.edge_shift)
        left = _edge_push(self.left_edge - ey, self.edge_cutoff, self.edge_shift)
        return line, self.k_boundary * (right - left)


def default_max_speed_mps(scene: SocialForceScene, goals_xy_m: np.ndarray, dt_s: float = DT_S) -> np.ndarray:
    """Default cap on v0, (B,): ``min(50, max(v_x0, u) + 5)`` m/s with the plan's mean speed ``u = max(g_x - x_0, 0) /
    T``."""
    horizon_s = max(scene.n_steps * dt_s, dt_s)
    u = np.maximum(np.asarray(goals_xy_m, dtype=np.float64)[:, 0] - scene.ego_xy0_m[:, 0], 0.0) / horizon_s
    fastest = np.maximum(np.maximum(scene.ego_vxy0_mps[:, 0], 0.0), u)
    return np.minimum(fastest + CATCH_UP_MARGIN_MPS, DEFAULT_MAX_SPEED_MPS)


def _max_speed(max_speed_mps: float | np.ndarray | None, scene: SocialForceScene, goals_xy_m: np.ndarray,
               dt_s: float) -> np.ndarray:
    if max_speed_mps is None:
        return default_max_speed_mps(scene, goals_xy_m, dt_s)
    return np.broadcast_to(np.asarray(max_speed_mps, dtype=np.float64), (len(scene),)).copy()


def _goals(goals_xy_m: np.ndarray, n: int) -> np.ndarray:
    g = np.asarray(goals_xy_m, dtype=np.float64).reshape(n, 2)
    if not np.isfinite(g).all():
        raise ValueError("goals_xy_m must be finite")
    return g


def social_force_terms(
    scene: SocialForceScene,
    params: SocialForceParams,
    goals_xy_m: np.ndarray,
    ego_xy_m: np.ndarray,
    ego_vxy_mps: np.ndarray,
    step: int = 0,
    *,
    dt_s: float = DT_S,
    max_speed_mps: float | np.ndarray | None = None,
) -> ForceTerms:
    """The force components on the ego in state ``ego_xy_m``, ``ego_vxy_mps`` (B, 2) at step ``step`` (t = step dt),
    with the neighbours and remaining time of that step, for inspection."""
    n = len(scene)
    goals = _goals(goals_xy_m, n)
    kernel = _Kernel(scene, as_params_batch(params, n), goals, _max_speed(max_speed_mps, scene, goals, dt_s), dt_s)
    exy = np.asarray(ego_xy_m, dtype=np.float64).reshape(n, 2)
    vxy = np.asarray(ego_vxy_mps, dtype=np.float64).reshape(n, 2)
    ex, ey, vx, vy = exy[:, 0], exy[:, 1], vxy[:, 0], vxy[:, 1]
    gx, gy = kernel.goal_force(ex, ey, vx, vy, (scene.n_steps - step) * dt_s)
    pre, fol, lat = kernel.neighbour_force(ex, ey, scene.nbr_x_m[step], scene.nbr_y_m[step])
    line, edge = kernel.lane_force(ey)
    zero = np.zeros(n)
    return ForceTerms(
        goal=np.stack([gx, gy], axis=1),
        preceding=np.stack([pre, zero], axis=1),
        following=np.stack([fol, zero], axis=1),
        lateral=np.stack([zero, lat], axis=1),
        lane_line=np.stack([zero, line], axis=1),
        boundary=np.stack([zero, edge], axis=1),
    )


def rollout_social_force_scene(
    scene: SocialForceScene,
    params: SocialForceParams,
    goals_xy_m: np.ndarray,
    *,
    dt_s: float = DT_S,
    max_speed_mps: float | np.ndarray | None = None,
    nbr_weights: np.ndarray | None = None,
) -> RolloutResult:
    """Roll the ego out for ``scene.n_steps`` steps of ``dt_s``. ``params``: one set or a batch (B,); ``goals_xy_m`` (B,
    2) [m]; ``max_speed_mps``: cap on v0, scalar or (B,) (default ``default_max_speed_mps``); ``nbr_weights`` (B, N):
    multipliers of each neighbour's repulsion (GNP)."""
    n = len(scene)
    f = scene.n_steps
    goals = _goals(goals_xy_m, n)
    weights = None
    if nbr_weights is not None:
        w = np.asarray(nbr_weights, dtype=np.float64)
        if w.shape != (n, scene.n_neighbours):
            raise ValueError(f"nbr_weights must be ({n}, {scene.n_neighbours}), got {w.shape}")
        weights = np.ascontiguousarray(w.T)
    kernel = _Kernel(scene, as_params_batch(params, n), goals, _max_speed(max_speed_mps, scene, goals, dt_s), dt_s,
                     nbr_weights=weights)
    ex = scene.ego_xy0_m[:, 0].copy()
    ey = scene.ego_xy0_m[:, 1].copy()
    vx = scene.ego_vxy0_mps[:, 0].copy()
    vy = scene.ego_vxy0_mps[:, 1].copy()
    out = np.empty((f, 6, n))  # x, y, vx, vy, ax, ay; step-major so each write is contiguous
    for k in range(f):
        gx, gy = kernel.goal_force(ex, ey, vx, vy, (f - k) * dt_s)
        pre, fol, lat = kernel.neighbour_force(ex, ey, scene.nbr_x_m[k], scene.nbr_y_m[k])
        line, edge = kernel.lane_force(ey)
        ax = np.clip(gx + pre + fol, AX_MIN_MPS2, AX_MAX_MPS2)
        ay = np.clip(gy + lat + line + edge, -AY_MAX_MPS2, AY_MAX_MPS2)
        new_vx = np.maximum(vx + ax * dt_s, 0.0)  # never reverse
        vy = vy + ay * dt_s
        step = out[k]
        np.subtract(new_vx, vx, out=step[4])
        step[4] /= dt_s
        step[5] = ay
        vx = new_vx
        ex = ex + vx * dt_s
        ey = ey + vy * dt_s
        step[0] = ex
        step[1] = ey
        step[2] = vx
        step[3] = vy
    res = out.transpose(2, 0, 1)  # (B, F, 6)
    return RolloutResult(
        xy_m=np.ascontiguousarray(res[..., 0:2]),
        vxy_mps=np.ascontiguousarray(res[..., 2:4]),
        axy_mps2=np.ascontiguousarray(res[..., 4:6]),
        dt_s=dt_s,
    )


def rollout_social_force(
    batch: ScenarioBatch,
    params: SocialForceParams,
    goals_xy_m: np.ndarray,
    neighbours: NeighbourPrediction,
    *,
    max_speed_mps: float | np.ndarray | None = None,
) -> RolloutResult:
    """Plan the ego of every scenario in ``batch`` towards ``goals_xy_m`` (B, 2) [m], given the neighbours' prediction
    (B, N, F, ...) whose horizon F sets the plan's (usually 125)."""
    scene = SocialForceScene.from_batch(batch, neighbours)
    return rollout_social_force_scene(scene, params, goals_xy_m, max_speed_mps=max_speed_mps)
