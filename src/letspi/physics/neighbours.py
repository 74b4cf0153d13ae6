"""Neighbour trajectory prediction over the planning horizon (what the ego planner reacts to).

``NeighbourPredictionMode``: ``constant_velocity``; ``idm`` (the paper's): each neighbour follows, with IDM, its
leader fixed at t = 0 (nearest ahead in its HighD lane among the visible neighbours and the ego, the ego at
constant velocity) and keeps its lateral position, all simulated jointly; ``ground_truth_oracle``: the recorded
future (leaks it: upper bounds only). Neighbours not visible at t = 0 cannot be predicted: invalid, xy and vxy 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from letspi.constants import DT_S, N_FUTURE, T0_INDEX
from letspi.physics.idm import IdmKernel, IdmParams, desired_speed_from_history, step_speed
from letspi.physics.types import NeighbourPrediction
from letspi.scenario.types import ScenarioBatch


class NeighbourPredictionMode(StrEnum):
    CONSTANT_VELOCITY = "constant_velocity"
    IDM = "idm"
    GROUND_TRUTH_ORACLE = "ground_truth_oracle"


def _t0_state(batch: ScenarioBatch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Neighbour xy, vxy at t = 0 (B, N, 2) float64 (0 where unknown) and visibility (B, N)."""
    xy = batch.nbr_xy_m[:, :, T0_INDEX].astype(np.float64)
    vxy = batch.nbr_vxy_mps[:, :, T0_INDEX].astype(np.float64)
    ok = batch.nbr_valid[:, :, T0_INDEX] & np.isfinite(xy).all(axis=-1) & np.isfinite(vxy).all(axis=-1)
    return np.where(ok[..., None], xy, 0.0), np.where(ok[..., None], vxy, 0.0), ok


def predict_constant_velocity(batch: ScenarioBatch, n_steps: int = N_FUTURE, dt_s: float = DT_S) -> NeighbourPrediction:
    """Constant-velocity prediction for t = dt .. n_steps dt: (B, N, F, 2) positions and velocities, (B, N, F) valid."""
    xy0, vxy0, ok = _t0_state(batch)
    t = (np.arange(1, n_steps + 1) * dt_s)[None, None, :, None]
    b, n = ok.shape
    # in place: these arrays are large (B * N * F * 2) and temporaries cost page faults
    xy = np.empty((b, n, n_steps, 2))
    np.multiply(vxy0[:, :, None, :], t, out=xy)
    xy += xy0[:, :, None, :]
    vxy = np.empty_like(xy)
    vxy[...] = vxy0[:, :, None, :]
    valid = np.empty((b, n, n_steps), dtype=bool)
    valid[...] = ok[:, :, None]
    return NeighbourPrediction(xy_m=xy, vxy_mps=vxy, valid=valid)


def idm_leaders(batch: ScenarioBatch) -> np.ndarray:
    """Leader of each neighbour at t = 0, (B, N): a neighbour slot, N for the ego, -1 for none (nearest ahead by
    centre x in the same HighD lane, visible vehicles only)."""
    xy0, _, ok = _t0_state(batch)
    b, n = ok.shape
    lane = np.where(ok, batch.nbr_lane_id[:, :, T0_INDEX], -1).astype(np.int16)
    cand_x = np.concatenate([xy0[:, :, 0], np.nan_to_num(batch.ego_xy0_m[:, :1].astype(np.float64))], axis=1)
    cand_lane = np.concatenate([lane, batch.ego_lane_id[:, T0_INDEX : T0_INDEX + 1].astype(np.int16)], axis=1)
    cand_ok = np.concatenate([ok, np.ones((b, 1), dtype=bool)], axis=1)
    # (B, N followers, N + 1 candidates)
    dx = cand_x[:, None, :] - xy0[:, :, 0][:, :, None]
    eligible = (
        cand_ok[:, None, :]
        & ok[:, :, None]
        & (cand_lane[:, None, :] == lane[:, :, None])
        & (lane[:, :, None] > 0)
        & (dx > 0.0)
    )
    eligible[:, np.arange(n), np.arange(n)] = False
    dist = np.where(eligible, dx, np.inf)
    leader = np.argmin(dist, axis=2)
    return np.where(np.isfinite(dist.min(axis=2)), leader, -1)


@dataclass(frozen=True)
class IdmStart:
    """The t = 0 state of the IDM prediction, (B, N) each: x, v (>= 0), y, visibility ``ok``, ``has_leader``, the
    leader's slot in [neighbours, ego], desired speeds, car/truck parameters, half length sums with the leader;
    and the ego's x and speed (B,), which it keeps."""

    x: np.ndarray
    v: np.ndarray
    y: np.ndarray
    ok: np.ndarray
    has_leader: np.ndarray
    lead_idx: np.ndarray
    desired_speed_mps: np.ndarray
    params: IdmParams
    half_len_m: np.ndarray
    ego_x_m: np.ndarray
    ego_v_mps: np.ndarray


def idm_start(batch: ScenarioBatch) -> IdmStart:
    """The t = 0 state and constants of ``predict_idm``."""
    xy0, vxy0, ok = _t0_state(batch)
    leader = idm_leaders(batch)
    has_leader = leader >= 0
    lead_idx = np.where(has_leader, leader, 0)
    hist = batch.history_slice
    nbr_len = np.nan_to_num(batch.nbr_length_m.astype(np.float64))
    cand_len = np.concatenate([nbr_len, batch.ego_length_m.astype(np.float64)[:, None]], axis=1)
    return IdmStart(
        x=xy0[:, :, 0].copy(), v=np.maximum(vxy0[:, :, 0], 0.0), y=xy0[:, :, 1], ok=ok, has_leader=has_leader,
        lead_idx=lead_idx,
        desired_speed_mps=desired_speed_from_history(batch.nbr_vxy_mps[:, :, hist, 0], batch.nbr_valid[:, :, hist]),
        params=IdmParams.for_classes(batch.nbr_class),
        half_len_m=0.5 * (nbr_len + np.take_along_axis(cand_len, lead_idx, axis=1)),
        ego_x_m=np.nan_to_num(batch.ego_xy0_m[:, 0].astype(np.float64)),
        ego_v_mps=np.nan_to_num(batch.ego_vxy0_mps[:, 0].astype(np.float64)),
    )


def predict_idm(batch: ScenarioBatch, n_steps: int = N_FUTURE, dt_s: float = DT_S) -> NeighbourPrediction:
    """IDM prediction (module docstring); shapes as ``predict_constant_velocity``."""
    st = idm_start(batch)
    b, n = st.ok.shape
    x, v, half_len, ego_x, ego_v = st.x, st.v, st.half_len_m, st.ego_x_m, st.ego_v_mps
    xs = np.empty((b, n, n_steps))
    vs = np.empty((b, n, n_steps))
    kernel = IdmKernel(st.desired_speed_mps, st.params)
    # the leaders' states are gathered from (B, N + 1) rows of [neighbours..., ego] by flat index
    cand_x = np.empty((b, n + 1))
    cand_v = np.empty((b, n + 1))
    cand_v[:, n] = ego_v
    flat_lead = st.lead_idx + (n + 1) * np.arange(b)[:, None]
    for k in range(n_steps):
        cand_x[:, :n] = x
        cand_x[:, n] = ego_x + ego_v * (k * dt_s)  # ego: constant velocity
        cand_v[:, :n] = v
        gap = np.where(st.has_leader, cand_x.take(flat_lead) - x - half_len, np.inf)
        acc = kernel(v, gap, cand_v.take(flat_lead))
        v = step_speed(v, acc, dt_s)
        x = x + v * dt_s
        xs[:, :, k] = x
        vs[:, :, k] = v
    return idm_prediction_of(st, xs, vs)


def idm_prediction_of(st: IdmStart, xs: np.ndarray, vs: np.ndarray) -> NeighbourPrediction:
    """The prediction of simulated x positions and speeds (B, N, F): invisible neighbours invalid (0), y kept."""
    b, n, n_steps = xs.shape
    ok = st.ok
    valid = np.broadcast_to(ok[:, :, None], (b, n, n_steps)).copy()
    y = np.broadcast_to(st.y[:, :, None], (b, n, n_steps))
    xy = np.where(valid[..., None], np.stack([xs, y], axis=-1), 0.0)
    vxy = np.where(valid[..., None], np.stack([vs, np.zeros_like(vs)], axis=-1), 0.0)
    return NeighbourPrediction(xy_m=xy, vxy_mps=vxy, valid=valid)


def ground_truth_oracle(batch: ScenarioBatch, n_steps: int = N_FUTURE) -> NeighbourPrediction:
    """ORACLE: the recorded neighbour future (leaks the future; upper-bound experiments only)."""
    sl = slice(T0_INDEX + 1, T0_INDEX + 1 + n_steps)
    xy = batch.nbr_xy_m[:, :, sl].astype(np.float64)
    vxy = batch.nbr_vxy_mps[:, :, sl].astype(np.float64)
    valid = batch.nbr_valid[:, :, sl] & np.isfinite(xy).all(axis=-1) & np.isfinite(vxy).all(axis=-1)
    if valid.shape[2] != n_steps:
        raise ValueError(f"the batch holds {valid.shape[2]} future frames, {n_steps} requested")
    return NeighbourPrediction(
        xy_m=np.where(valid[..., None], xy, 0.0), vxy_mps=np.where(valid[..., None], vxy, 0.0), valid=valid
    )


def predict_neighbours(
    batch: ScenarioBatch, mode: NeighbourPredictionMode | str, n_steps: int = N_FUTURE
) -> NeighbourPrediction:
    """Dispatch on ``mode``: xy (B, N, F, 2), vxy (B, N, F, 2), valid (B, N, F)."""
    mode = NeighbourPredictionMode(mode)
    if mode is NeighbourPredictionMode.CONSTANT_VELOCITY:
        return predict_constant_velocity(batch, n_steps)
    if mode is NeighbourPredictionMode.IDM:
        return predict_idm(batch, n_steps)
    return ground_truth_oracle(batch, n_steps)
