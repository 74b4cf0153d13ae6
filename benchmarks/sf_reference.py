"""Scalar reference of the social force rollout (tests and benchmark only): the equations of
``social_force.rollout_social_force_scene`` written out term by term in Python loops, slow by design.
"""

from __future__ import annotations

import math

import numpy as np

from letspi.constants import DT_S
from letspi.physics import social_force as sf
from letspi.physics.params import SocialForceParams, as_params_batch
from letspi.physics.types import RolloutResult


def rollout_social_force_reference(
    scene: sf.SocialForceScene,
    params: SocialForceParams,
    goals_xy_m: np.ndarray,
    *,
    dt_s: float = DT_S,
    max_speed_mps: float | np.ndarray | None = None,
) -> RolloutResult:
    """Same contract as ``rollout_social_force_scene``; per-scenario Python loops."""
    n = len(scene)
    f = scene.n_steps
    p = as_params_batch(params, n)
    goals = np.asarray(goals_xy_m, dtype=np.float64).reshape(n, 2)
    vmax_all = (
        sf.default_max_speed_mps(scene, goals, dt_s)
        if max_speed_mps is None
        else np.broadcast_to(np.asarray(max_speed_mps, dtype=np.float64), (n,))
    )
    out = np.empty((n, f, 6))
    sigma2 = sf.LANE_LINE_SIGMA_M**2
    for b in range(n):
        row = p.row(b)
        gx_goal, gy_goal = float(goals[b, 0]), float(goals[b, 1])
        vmax = float(vmax_all[b])
        lw = float(scene.lane_width_m[b])
        ego_len = float(scene.ego_length_m[b])
        ego_wid = float(scene.ego_width_m[b])
        n_nbr = scene.n_neighbours
        nbr_x = scene.nbr_x_m[:, :, b].tolist()  # [step][neighbour]
        nbr_y = scene.nbr_y_m[:, :, b].tolist()
        nbr_valid = scene.nbr_valid[:, :, b].tolist()
        half_len = [0.5 * (ego_len + float(scene.nbr_length_m[j, b])) for j in range(n_nbr)]
        half_wid = [0.5 * (ego_wid + float(scene.nbr_width_m[j, b])) for j in range(n_nbr)]
        lines = [float(y) for y, known in zip(scene.line_y_m[:, b], scene.line_known[:, b], strict=True) if known]
        right_edge = float(scene.right_edge_y_m[b])
        left_edge = float(scene.left_edge_y_m[b])
        cutoff = max(0.5 * lw - 0.5 * ego_wid, sf.EDGE_MIN_CUTOFF_M)
        ex, ey = float(scene.ego_xy0_m[b, 0]), float(scene.ego_xy0_m[b, 1])
        vx, vy = float(scene.ego_vxy0_mps[b, 0]), float(scene.ego_vxy0_mps[b, 1])
        pass_speed = max(gx_goal - ex, 0.0) / max(f * dt_s, dt_s)
        for k in range(f):
            # goal attraction (Eq. 4 with the guards of the module docstring)
            remaining_raw = (f - k) * dt_s
            overrun = max(sf.MIN_REMAINING_TIME_S - remaining_raw, 0.0)
            dgx, dgy = gx_goal + pass_speed * overrun - ex, gy_goal - ey
            dist = max(math.hypot(dgx, dgy), sf.MIN_GOAL_DISTANCE_M)
            remaining = max(remaining_raw, sf.MIN_REMAINING_TIME_S)
            v0 = min(dist / remaining, vmax)
            vdx = max(v0 / dist * dgx, 0.0)
            vdy = min(max(v0 / dist * dgy, -sf.MAX_LATERAL_DESIRED_SPEED_MPS), sf.MAX_LATERAL_DESIRED_SPEED_MPS)
            fx = (vdx - vx) / row.tau_s
            fy = (vdy - vy) / row.tau_s
            # neighbours
            for j in range(n_nbr):
                if not nbr_valid[k][j]:
                    continue
                dx = nbr_x[k][j] - ex
                dy = nbr_y[k][j] - ey
                gap_x = max(abs(dx) - half_len[j], 0.0)
                gap_y = max(abs(dy) - half_wid[j], 0.0)
                mag = math.exp(-math.sqrt(gap_x * gap_x + gap_y * gap_y) / row.r_col_m)
                if abs(dy) < max(0.5 * lw, half_wid[j]):
                    fx += -row.k_np * mag if dx > 0.0 else row.k_nf * mag
                elif abs(dy) < sf.LATERAL_RANGE_LANES * lw:
                    fy += -row.k_nl * mag * math.copysign(1.0, dy)
            # lane lines (Gaussian) and road edges (force-shifted inverse square, pushing inwards)
            for y_m in lines:
                dm = ey - y_m
                fy += row.k_cline * dm / sigma2 * math.exp(-dm * dm / (2.0 * sigma2))
            for inward_dir, side in ((1.0, ey - right_edge - 0.5 * ego_wid), (-1.0, left_edge - ey - 0.5 * ego_wid)):
                side = max(side, sf.EDGE_MIN_DISTANCE_M)
                if side < cutoff:
                    fy += row.k_boundary * inward_dir * (1.0 / side**3 - 1.0 / cutoff**3)
            ax = min(max(fx, sf.AX_MIN_MPS2), sf.AX_MAX_MPS2)
            ay = min(max(fy, -sf.AY_MAX_MPS2), sf.AY_MAX_MPS2)
            new_vx = max(vx + ax * dt_s, 0.0)
            out[b, k, 4] = (new_vx - vx) / dt_s
            out[b, k, 5] = ay
            vx = new_vx
            vy = vy + ay * dt_s
            ex = ex + vx * dt_s
            ey = ey + vy * dt_s
            out[b, k, 0:4] = (ex, ey, vx, vy)
    return RolloutResult(xy_m=out[..., 0:2].copy(), vxy_mps=out[..., 2:4].copy(), axy_mps2=out[..., 4:6].copy(),
                         dt_s=dt_s)
