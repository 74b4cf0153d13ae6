"""The planner's view at a replanning instant (``replanning_batch``), and the engine's replanning step
(``Replanner``: the plans due at a frame, or None; the engine only follows plans)."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import Literal, Protocol, runtime_checkable

import numpy as np

from letspi.constants import N_FUTURE, N_TOTAL, T0_INDEX
from letspi.planners.base import PlanBatch, Planner
from letspi.scenario.queries import OFF_ROAD, lane_index_of
from letspi.scenario.types import CONTEXT_FIELDS, ScenarioBatch

FuturePolicy = Literal["none", "log"]


@dataclass(frozen=True)
class SimulatedStates:
    """Simulated states of K scenarios over the source batch's T frames (not simulated yet: NaN / False / 0).
    ego_xy_m, ego_vxy_mps, ego_axy_mps2: (K, T, 2) in the source ego frame; ego_lane_id: (K, T); nbr_xy_m,
    nbr_vxy_mps: (K, N, T, 2); nbr_valid, nbr_lane_id: (K, N, T)."""

    ego_xy_m: np.ndarray
    ego_vxy_mps: np.ndarray
    ego_axy_mps2: np.ndarray
    ego_lane_id: np.ndarray
    nbr_xy_m: np.ndarray
    nbr_vxy_mps: np.ndarray
    nbr_valid: np.ndarray
    nbr_lane_id: np.ndarray


def _fill_value(arr: np.ndarray) -> object:
    if arr.dtype == bool:
        return False
    if np.issubdtype(arr.dtype, np.floating):
        return np.nan
    return 0


def frame_axis(arr: np.ndarray, n_frames: int) -> int | None:
    """The frame axis of a batch field (first non-batch axis of length ``n_frames``), or None."""
    for axis in range(1, arr.ndim):
        if arr.shape[axis] == n_frames:
            return axis
    return None


def _window(arr: np.ndarray, axis: int, shift: int) -> np.ndarray:
    """``out[..., i, ...] = arr[..., i + shift, ...]`` along ``axis``, filled outside the source."""
    out = np.full(arr.shape, _fill_value(arr), dtype=arr.dtype)
    n = arr.shape[axis]
    lo, hi = max(0, -shift), min(n, n - shift)
    if hi > lo:
        dst = [slice(None)] * arr.ndim
        src = [slice(None)] * arr.ndim
        dst[axis] = slice(lo, hi)
        src[axis] = slice(lo + shift, hi + shift)
        out[tuple(dst)] = arr[tuple(src)]
    return out


def lane_ids_from_y(marking_y_m: np.ndarray, lane_ids: np.ndarray, y_m: np.ndarray) -> np.ndarray:
    """HighD lane ids (0 off the road or unknown) of lateral positions y_m (K, ...) given markings (K, M)."""
    idx = lane_index_of(marking_y_m, y_m)
    flat = idx.reshape(idx.shape[0], -1)
    ids = np.take_along_axis(np.asarray(lane_ids, dtype=np.int64), np.clip(flat, 0, None), axis=1)
    return np.where(flat == OFF_ROAD, 0, ids).reshape(idx.shape).astype(np.int8)


def replanning_batch(
    source: ScenarioBatch, sim: SimulatedStates, frame: int, future: FuturePolicy = "none"
) -> tuple[ScenarioBatch, np.ndarray]:
    """The batch a planner sees at ``frame`` (>= ``T0_INDEX``), and ``centre_xy_m`` (K, 2), the ego's simulated
    centre there (source ego frame), to add to its plans. The view is the source shifted by ``frame - T0_INDEX``
    frames and re-centred; the simulated states overwrite the history; the future is blank (``future="none"``) or the
    log (``future="log"``)."""
    n_frames = source.ego_xy_m.shape[1]
    if not T0_INDEX <= frame < n_frames:
        raise ValueError(f"replanning frame {frame} outside [{T0_INDEX}, {n_frames})")
    if future not in ("none", "log"):
        raise ValueError(f"future must be 'none' or 'log', got {future!r}")
    centre = sim.ego_xy_m[:, frame].astype(np.float64)
    if not np.isfinite(centre).all():
        raise ValueError(f"the simulated ego position at frame {frame} is not finite")
    out = _shifted_fields(source, sim, frame, future)
    _recentre(out, source, centre, shift=frame - T0_INDEX)
    if future == "none":  # context vehicles are future-only ground truth: never part of a planner's view
        out.update({name: out[name][:, :0] for name in CONTEXT_FIELDS})
    return ScenarioBatch(**out), centre


def _shifted_fields(
    source: ScenarioBatch, sim: SimulatedStates, frame: int, future: FuturePolicy
) -> dict[str, np.ndarray]:
    """Every field of ``source`` shifted so that ``frame`` becomes ``T0_INDEX``: the own states' history
    from ``sim``, the future blanked with ``future="none"``, fields without a frame axis copied."""
    n_frames = source.ego_xy_m.shape[1]
    shift = frame - T0_INDEX
    hist = slice(0, T0_INDEX + 1)
    src_hist = slice(shift, frame + 1)
    own = {f.name: getattr(sim, f.name) for f in fields(SimulatedStates)}
    out: dict[str, np.ndarray] = {}
    for f in fields(ScenarioBatch):
        arr = np.asarray(getattr(source, f.name))
        axis = frame_axis(arr, n_frames)
        if axis is None:
            out[f.name] = arr.copy()
            continue
        if future == "none" and f.name in own:  # every frame is overwritten below: no need to shift the source
            win = np.full(arr.shape, _fill_value(arr), dtype=arr.dtype)
        else:
            win = _window(arr, axis, shift)
        index = [slice(None)] * arr.ndim
        if future == "none":
            index[axis] = slice(T0_INDEX + 1, n_frames)
            win[tuple(index)] = _fill_value(arr)
        if f.name in own:
            index[axis] = hist
            src_index = [slice(None)] * arr.ndim
            src_index[axis] = src_hist
            win[tuple(index)] = own[f.name][tuple(src_index)].astype(arr.dtype)
        out[f.name] = win
    return out


def _recentre(out: dict[str, np.ndarray], source: ScenarioBatch, centre: np.ndarray, shift: int) -> None:
    """Move the view's positions by the ego's ``centre`` (K, 2), its markings by its y, ``frame0`` by ``shift``."""
    for name, arr in out.items():
        if name.endswith("_xy_m"):
            shape = (len(centre),) + (1,) * (arr.ndim - 2) + (2,)
            out[name] = (arr.astype(np.float64) - centre.reshape(shape)).astype(arr.dtype)
    out["marking_y_m"] = (out["marking_y_m"].astype(np.float64) - centre[:, 1:2]).astype(source.marking_y_m.dtype)
    out["frame0"] = (np.asarray(source.frame0) + shift).astype(source.frame0.dtype)


@dataclass(frozen=True)
class Replan:
    """Plans made at one frame for D of the K scenarios of a lockstep group: ``rows`` (D,) their positions 0..K-1;
    ``xy_m``, ``vxy_mps`` (D, F, 2) in the *source* ego frame, point i at frame + 1 + i; ``goals_xy_m`` (D, 2), NaN
    if none; ``follow_until`` (D,) the last frame each is followed (<= ``frame + F``, ``N_TOTAL - 1``); ``info``
    name -> (D,); ``plan_s`` planning wall time [s]."""

    rows: np.ndarray
    xy_m: np.ndarray
    vxy_mps: np.ndarray
    goals_xy_m: np.ndarray
    follow_until: np.ndarray
    info: dict[str, np.ndarray] = field(default_factory=dict)
    plan_s: float = 0.0


class Replanner(Protocol):
    """The engine's replanning step. ``frames``: the frames (>= ``T0_INDEX``, ascending) at which ``plans`` may plan
    (the slots of ``ClosedLoopChunk.plan_xy_m``); ``plans(frame, states)``: after each simulated frame; None when
    nothing is due."""

    @property
    def frames(self) -> Sequence[int]: ...

    def plans(self, frame: int, states: SimulatedStates) -> Replan | None: ...


@runtime_checkable
class Closing(Protocol):
    """A replanner with work in flight (model calls) to drop when its group is done."""

    def close(self) -> None: ...


def replan_frames_of(replan_every: int) -> list[int]:
    """Frames (source indexing) at which plans are made: t = 0, then every ``replan_every``."""
    return list(range(T0_INDEX, N_TOTAL - 1, replan_every))


def plan_in_batches(planner: Planner, batch: ScenarioBatch) -> PlanBatch:
    """``planner.plan`` over ``batch`` in sub-batches of ``planner.batch_size``."""
    step = max(1, int(planner.batch_size))
    if len(batch) <= step:
        return planner.plan(batch)
    parts = [planner.plan(batch.take(slice(s, s + step))) for s in range(0, len(batch), step)]
    info_keys = set.intersection(*(set(p.info) for p in parts))
    return PlanBatch(
        xy_m=np.concatenate([p.xy_m for p in parts]),
        vxy_mps=np.concatenate([p.vxy_mps for p in parts]),
        goals_xy_m=np.concatenate([p.goals_xy_m for p in parts]),
        info={k: np.concatenate([np.asarray(p.info[k]) for p in parts]) for k in sorted(info_keys)},
    )


class PeriodicReplanner:
    """Every scenario at t = 0 and every ``replan_every`` frames, one batched planner call; only 1-D numeric
    ``PlanBatch.info`` entries are kept."""

    def __init__(self, planner: Planner, batch: ScenarioBatch, replan_every: int, future: FuturePolicy) -> None:
        self.planner = planner
        self.batch = batch
        self.replan_every = int(replan_every)
        self.future: FuturePolicy = future
        self._frames = replan_frames_of(self.replan_every)
        self._due = set(self._frames)

    @property
    def frames(self) -> list[int]:
        return self._frames

    def plans(self, frame: int, states: SimulatedStates) -> Replan | None:
        """At a frame due: the planner's view of the simulated history, its plans, back in the simulation frame."""
        if frame not in self._due:
            return None
        t0 = time.perf_counter()
        view, centre = replanning_batch(self.batch, states, frame, self.future)
        plan, info = self._plan(frame, view)
        return self._replan(plan, centre, frame, info, time.perf_counter() - t0)

    def _plan(self, frame: int, view: ScenarioBatch) -> tuple[PlanBatch, dict[str, np.ndarray]]:
        """The plans of every scenario of ``view`` and per-scenario info: the whole planner, in sub-batches;
        ``planner_cpu_ms``, CPU of this thread per scenario (model calls included)."""
        k = len(self.batch)
        cpu0 = time.thread_time()
        plan = plan_in_batches(self.planner, view)
        return plan, {"planner_cpu_ms": np.full(k, 1e3 * (time.thread_time() - cpu0) / max(k, 1))}

    def _replan(self, plan: PlanBatch, centre: np.ndarray, frame: int, extra_info: dict[str, np.ndarray],
                plan_s: float) -> Replan:
        """Plans made in the ego-centred view back in the simulation frame, followed until the next replan; only
        1-D numeric info kept (the plan's and ``extra_info``)."""
        k = len(self.batch)
        if plan.xy_m.shape != (k, N_FUTURE, 2):
            raise ValueError(f"planner {self.planner.name!r} returned plans of shape {plan.xy_m.shape}, "
                             f"expected {(k, N_FUTURE, 2)}")
        info = {key: np.asarray(val) for key, val in plan.info.items()}
        info.update(extra_info)
        return Replan(
            rows=np.arange(k),
            xy_m=np.asarray(plan.xy_m, dtype=np.float64) + centre[:, None, :],
            vxy_mps=np.asarray(plan.vxy_mps, dtype=np.float64),
            goals_xy_m=np.asarray(plan.goals_xy_m, dtype=np.float64) + centre,
            follow_until=np.full(k, min(frame + self.replan_every, N_TOTAL - 1), dtype=np.int64),
            info={key: arr for key, arr in info.items() if arr.ndim == 1 and arr.dtype.kind in "biuf"},
            plan_s=plan_s,
        )
