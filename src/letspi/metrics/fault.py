"""At-fault collisions: who caused a contact between the planned ego and a replayed (non-reactive) neighbour.

As in nuPlan, a contact the ego could not have avoided is not charged to it. Each colliding pair is classified
at its first contact step s: **side** when the boxes did not overlap laterally at some step within
``fault_reaction_time_s`` before s, at fault when the ego did at least half of the lateral closing since;
otherwise **front** when the neighbour's centre was ahead of the ego's just before contact, at fault; otherwise
**rear**, at fault only when at some step f <= s the ego braked harder than max(``fault_comfort_decel_mps2``,
the largest need so far), a need being the larger of the ego's DRAC towards its preceding vehicle and that
vehicle's deceleration. Only future steps count; decelerations are finite differences from the t = 0 state
(``kinematics``), the neighbours' of their recorded velocities (the first step copies the second).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from letspi.metrics.inputs import MetricInputs

#: collision kinds, indexed by the codes in ``FaultResult.pair_kind``
KINDS: tuple[str, ...] = ("none", "front", "side", "rear")
NONE, FRONT, SIDE, REAR = range(4)


@dataclass(frozen=True)
class FaultResult:
    """Per pair (B, N): ``pair_kind`` (int8 code into ``KINDS``), ``pair_at_fault``, ``pair_contact_step`` (-1 none).
    Per scenario (B,): ``collision_kind`` of the first collision ("none" without), ``collision_at_fault`` (any pair),
    ``collision_fault_step`` / ``collision_fault_nbr`` of the first at-fault contact (-1 none)."""

    pair_kind: np.ndarray
    pair_at_fault: np.ndarray
    pair_contact_step: np.ndarray
    collision_kind: np.ndarray
    collision_at_fault: np.ndarray
    collision_fault_step: np.ndarray
    collision_fault_nbr: np.ndarray


def _unjustified_braking(
    inp: MetricInputs,
    b_idx: np.ndarray,
    contact_step: np.ndarray,
    ego_acc_lon_mps2: np.ndarray,
    drac_mps2: np.ndarray,
    preceding_nbr: np.ndarray,
    comfort_decel_mps2: float,
    dt_s: float,
) -> np.ndarray:
    """(Q,) bool: the ego of scenario b_idx[q] braked harder than allowed at some step <= contact_step[q]."""
    f = ego_acc_lon_mps2.shape[1]
    decel = -ego_acc_lon_mps2[b_idx]  # (Q, F)
    vx = inp.nbr_vxy_mps[b_idx, :, :, 0]  # (Q, N, F)
    acc = np.diff(vx, axis=2, prepend=np.nan) / dt_s
    if f > 1:
        acc[..., 0] = acc[..., 1]
    prec = preceding_nbr[b_idx]  # (Q, F)
    lead_acc = np.take_along_axis(acc, np.maximum(prec, 0)[:, None, :], axis=1)[:, 0]
    lead_decel = np.where(prec >= 0, np.nan_to_num(-lead_acc, nan=0.0), 0.0)
    need = np.maximum(np.nan_to_num(drac_mps2[b_idx], nan=0.0), lead_decel)
    allowed = np.maximum(comfort_decel_mps2, np.maximum.accumulate(need, axis=1))
    before = np.arange(f)[None, :] <= contact_step[:, None]
    out: np.ndarray = ((decel > allowed) & before).any(axis=1)
    return out


def _classify_pairs(inp: MetricInputs, overlap: np.ndarray, bi: np.ndarray, ni: np.ndarray, reaction_time_s: float,
                    dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(first contact step, kind, ego at fault) of the P colliding pairs (scenario ``bi``, slot ``ni``),
    (P,) each; a rear collision's fault is decided afterwards (``_unjustified_braking``)."""
    f = overlap.shape[2]
    s = overlap[bi, ni].argmax(axis=1)  # (P,) first contact step
    frames = np.arange(f)[None, :]
    apart = inp.nbr_valid[bi, ni] & ~inp.lateral_overlap[bi, ni]  # (P, F); invalid steps: unknown
    onset = np.where(apart & (frames < s[:, None]), frames, -1).max(axis=1)  # last step apart laterally
    window = max(round(reaction_time_s / dt_s), 1)
    lateral = (onset >= 0) & (s - onset <= window)
    o = np.maximum(onset, 0)
    sgn = np.sign(inp.dy_m[bi, ni, o])
    ego_y = inp.ego_xy_m[bi, :, 1]
    nbr_y = inp.nbr_xy_m[bi, ni, :, 1]
    rows = np.arange(bi.size)
    ego_in = sgn * (ego_y[rows, s] - ego_y[rows, o])
    nbr_in = -sgn * (nbr_y[rows, s] - nbr_y[rows, o])
    dx_before = inp.dx_m[bi, ni, np.maximum(s - 1, 0)]
    ahead = np.where(np.isfinite(dx_before), dx_before, inp.dx_m[bi, ni, s]) > 0
    kind = np.where(lateral, SIDE, np.where(ahead, FRONT, REAR)).astype(np.int8)
    return s, kind, np.where(lateral, ego_in >= nbr_in, kind == FRONT)


def at_fault_collisions(
    inp: MetricInputs,
    overlap: np.ndarray,
    first_step: np.ndarray,
    first_nbr: np.ndarray,
    ego_acc_lon_mps2: np.ndarray,
    drac_mps2: np.ndarray,
    preceding_nbr: np.ndarray,
    *,
    reaction_time_s: float = 1.0,
    comfort_decel_mps2: float = 3.0,
    dt_s: float = 0.04,
) -> FaultResult:
    """Classify every colliding pair and flag the ego's fault (module doc): ``overlap`` (B, N, F) box overlap;
    ``first_step``, ``first_nbr`` (B,) the first collision; ``ego_acc_lon_mps2`` (B, F) planned longitudinal
    acceleration; ``drac_mps2``, ``preceding_nbr`` (B, F) from ``drac`` and ``ttc``."""
    b, n, _ = overlap.shape
    pair_kind = np.zeros((b, n), dtype=np.int8)
    pair_fault = np.zeros((b, n), dtype=bool)
    pair_step = np.full((b, n), -1, dtype=np.int64)
    bi, ni = np.nonzero(overlap.any(axis=2))
    if bi.size:
        s, kind, fault = _classify_pairs(inp, overlap, bi, ni, reaction_time_s, dt_s)
        rear = np.flatnonzero(kind == REAR)
        if rear.size:
            fault[rear] = _unjustified_braking(
                inp, bi[rear], s[rear], ego_acc_lon_mps2, drac_mps2, preceding_nbr, comfort_decel_mps2, dt_s
            )
        pair_kind[bi, ni] = kind
        pair_fault[bi, ni] = fault
        pair_step[bi, ni] = s

    rows_b = np.arange(b)
    has = first_nbr >= 0
    first_kind = np.where(has, pair_kind[rows_b, np.maximum(first_nbr, 0)], NONE)
    # first at-fault contact: smallest step, then lowest slot
    order = np.where(pair_fault, pair_step * max(n, 1) + np.arange(n)[None, :], np.iinfo(np.int64).max)
    k = order.argmin(axis=1) if n else np.zeros(b, dtype=np.int64)
    any_fault: np.ndarray = np.asarray(pair_fault.any(axis=1))
    return FaultResult(
        pair_kind=pair_kind,
        pair_at_fault=pair_fault,
        pair_contact_step=pair_step,
        collision_kind=np.asarray(KINDS, dtype=object)[first_kind],
        collision_at_fault=any_fault,
        collision_fault_step=np.where(any_fault, pair_step[rows_b, k] if n else -1, -1),
        collision_fault_nbr=np.where(any_fault, k, -1),
    )
