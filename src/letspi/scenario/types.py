"""Planning scenarios as a struct of arrays: ``ScenarioBatch``, one type for one or many scenarios.

The ego frame of every array: origin at the ego's box centre at t = 0, x along its travel, y to its left, SI
units. From HighD image axes (y down) with the ego centre ``(cx0, cy0)``: direction 2 has
``x = cx - cx0, y = -(cy - cy0)``, direction 1 ``x = -(cx - cx0), y = cy - cy0`` (a 180° turn, right-handed);
velocities alike. Markings become lines ``y = marking_y_m``, the outermost two road edges. Shapes: B scenarios,
T = ``N_TOTAL`` frames (``N_HISTORY`` in a history-only view), N neighbour slots, M markings; frame ``T0_INDEX``
is t = 0, later frames are ground truth for evaluation only.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from letspi.constants import N_FUTURE, N_HISTORY, N_TOTAL, T0_INDEX

SCHEMA_VERSION = 3
"""2: ``recording_key`` (vehicle identity across datasets). 3: neighbours chosen at t = 0; context vehicles."""

VEHICLE_CLASS_CAR = 0
VEHICLE_CLASS_TRUCK = 1
VEHICLE_CLASS_NONE = -1
VEHICLE_CLASS_NAMES = {VEHICLE_CLASS_CAR: "Car", VEHICLE_CLASS_TRUCK: "Truck"}

#: Context-vehicle fields (future frames only, padded along their axis C; see ``ScenarioBatch``).
CONTEXT_FIELDS = ("ctx_id", "ctx_class", "ctx_length_m", "ctx_width_m", "ctx_xy_m", "ctx_vxy_mps", "ctx_valid")
#: Per-frame fields: ``ego_*`` have the time axis at 1, ``nbr_*`` at 2.
_TIME_FIELDS = ("ego_xy_m", "ego_vxy_mps", "ego_axy_mps2", "ego_lane_id", "nbr_xy_m", "nbr_vxy_mps", "nbr_valid",
                "nbr_lane_id")


@dataclass(frozen=True)
class ScenarioBatch:
    """B ego-centric planning scenarios; every array has the leading batch axis.

    Meta (B,): ``scenario_id`` str ``"r{recording:02d}_v{ego_id}_f{frame0}"``; ``recording_id``, ``location_id``,
    ``ego_id``, ``frame0`` (HighD frame at t = 0) int32; ``recording_key`` str, a content hash of the recording (ids
    repeat across datasets, so a vehicle is (recording_key, ego_id)); ``driving_direction`` int8 (1 or 2);
    ``speed_limit_mps`` float32 (NaN: none); ``ego_class`` int8 (``VEHICLE_CLASS_*``); ``ego_length_m``,
    ``ego_width_m``. Ego: ``ego_xy_m``, ``ego_vxy_mps``, ``ego_axy_mps2`` (B, T, 2) float32; ``ego_lane_id`` (B, T)
    int8, HighD laneId. Neighbours (what a planner sees, chosen at t = 0): ``nbr_id`` (B, N) int32, ``nbr_class`` int8,
    ``nbr_length_m``, ``nbr_width_m`` float32; ``nbr_xy_m``, ``nbr_vxy_mps`` (B, N, T, 2) float32, NaN where not
    visible; ``nbr_valid`` (B, N, T) bool (in the recording then); ``nbr_lane_id`` (B, N, T) int8, 0 where not visible.
    Empty slots have id 0, class -1, size 0 and are never valid. Road (M markings ascending in y, right edge to left
    edge): ``marking_y_m`` (B, M) float32, NaN padded; ``marking_is_edge`` (B, M) bool; ``lane_ids`` (B, M - 1) int8,
    laneId between markings k and k + 1 (0: padding). Context vehicles (scored, never shown to a planner; C slots padded
    to the widest; F = ``N_FUTURE`` frames, frame f at t = (f + 1) dt; C = 0 in a history-only view): ``ctx_id`` int32,
    ``ctx_class`` int8, ``ctx_length_m``, ``ctx_width_m`` float32 (B, C); ``ctx_xy_m``, ``ctx_vxy_mps`` (B, C, F, 2)
    float32, NaN where absent; ``ctx_valid`` (B, C, F) bool."""

    scenario_id: np.ndarray
    recording_id: np.ndarray
    recording_key: np.ndarray
    location_id: np.ndarray
    ego_id: np.ndarray
    frame0: np.ndarray
    driving_direction: np.ndarray
    speed_limit_mps: np.ndarray
    ego_class: np.ndarray
    ego_length_m: np.ndarray
    ego_width_m: np.ndarray
    ego_xy_m: np.ndarray
    ego_vxy_mps: np.ndarray
    ego_axy_mps2: np.ndarray
    ego_lane_id: np.ndarray
    nbr_id: np.ndarray
    nbr_class: np.ndarray
    nbr_length_m: np.ndarray
    nbr_width_m: np.ndarray
    nbr_xy_m: np.ndarray
    nbr_vxy_mps: np.ndarray
    nbr_valid: np.ndarray
    nbr_lane_id: np.ndarray
    marking_y_m: np.ndarray
    marking_is_edge: np.ndarray
    lane_ids: np.ndarray
    ctx_id: np.ndarray
    ctx_class: np.ndarray
    ctx_length_m: np.ndarray
    ctx_width_m: np.ndarray
    ctx_xy_m: np.ndarray
    ctx_vxy_mps: np.ndarray
    ctx_valid: np.ndarray

    def __post_init__(self) -> None:
        b = len(self.scenario_id)
        for f in fields(self):
            arr = getattr(self, f.name)
            if not isinstance(arr, np.ndarray):
                raise TypeError(f"ScenarioBatch.{f.name} must be a numpy array, got {type(arr).__name__}")
            if arr.shape[:1] != (b,):
                raise ValueError(f"ScenarioBatch.{f.name} has leading shape {arr.shape[:1]}, expected ({b},)")
        if self.ego_xy_m.shape[1:] not in ((N_TOTAL, 2), (N_HISTORY, 2)):
            raise ValueError(f"ScenarioBatch.ego_xy_m must be (B, {N_TOTAL}, 2) or, history only, "
                             f"(B, {N_HISTORY}, 2); got {self.ego_xy_m.shape}")
        t = self.n_frames
        for name in _TIME_FIELDS:
            arr = getattr(self, name)
            axis = 1 if name.startswith("ego_") else 2
            if arr.shape[axis] != t:
                raise ValueError(f"ScenarioBatch.{name} has {arr.shape[axis]} frames, ego_xy_m has {t}")
        c = self.ctx_id.shape[1:2]
        for name in CONTEXT_FIELDS:
            arr = getattr(self, name)
            if arr.shape[1:2] != c or (arr.ndim > 2 and arr.shape[2] != N_FUTURE):
                raise ValueError(f"ScenarioBatch.{name} has shape {arr.shape}: context fields are (B, C) or "
                                 f"(B, C, {N_FUTURE}, ...) with one C (ctx_id has {c})")

    @classmethod
    def from_single(cls, **values: object) -> ScenarioBatch:
        """A batch of one from per-scenario values (arrays without the batch axis, scalars for meta)."""
        def one(value: object) -> np.ndarray:
            return np.array([value], dtype=object) if isinstance(value, str) else np.asarray([value])

        return cls(**{f.name: one(values[f.name]) for f in fields(cls)})

    def __len__(self) -> int:
        return len(self.scenario_id)

    @property
    def n_neighbours(self) -> int:
        """Number of neighbour slots N."""
        return int(self.nbr_id.shape[1])

    def take(self, indices: np.ndarray | list[int] | slice) -> ScenarioBatch:
        """A sub-batch (copying fancy indexing; a slice gives views)."""
        return ScenarioBatch(**{f.name: getattr(self, f.name)[indices] for f in fields(self)})

    @property
    def n_frames(self) -> int:
        """Frames T per scenario: ``N_TOTAL`` (history and future) or ``N_HISTORY`` (history only)."""
        return int(self.ego_xy_m.shape[1])

    @property
    def has_future(self) -> bool:
        """Whether the recorded future (frames after ``T0_INDEX``) is in this batch."""
        return self.n_frames > N_HISTORY

    def history(self) -> ScenarioBatch:
        """What a planner may see: every per-frame array cut at t = 0 and no context vehicles. The future is absent, not
        blanked, so code that reads it by mistake fails loudly."""
        if not self.has_future:
            return self
        cut = {name: (getattr(self, name)[:, :N_HISTORY] if name.startswith("ego_")
                      else getattr(self, name)[:, :, :N_HISTORY]) for name in _TIME_FIELDS}
        no_context = {name: getattr(self, name)[:, :0] for name in CONTEXT_FIELDS}
        return replace(self, **cut, **no_context)

    # Convenience views at t = 0 (what a planner may see) -------------------------------------
    @property
    def ego_xy0_m(self) -> np.ndarray:
        """Ego position at t = 0, (B, 2); zero by construction of the ego frame."""
        return self.ego_xy_m[:, T0_INDEX]

    @property
    def ego_vxy0_mps(self) -> np.ndarray:
        """Ego velocity at t = 0, (B, 2)."""
        return self.ego_vxy_mps[:, T0_INDEX]

    @property
    def history_slice(self) -> slice:
        return slice(0, T0_INDEX + 1)

    @property
    def future_slice(self) -> slice:
        return slice(T0_INDEX + 1, N_TOTAL)


#: Fields whose axis 1 is padded to the widest batch when concatenating, with their fill value.
_PADDED: dict[str, object] = {
    "marking_y_m": np.nan, "marking_is_edge": False, "lane_ids": 0,
    "ctx_id": 0, "ctx_class": VEHICLE_CLASS_NONE, "ctx_length_m": 0.0, "ctx_width_m": 0.0,
    "ctx_xy_m": np.nan, "ctx_vxy_mps": np.nan, "ctx_valid": False,
}


def concat_batches(batches: list[ScenarioBatch]) -> ScenarioBatch:
    """Concatenate batches, padding the marking axis (M) and the context axis (C) to the widest batch."""
    if not batches:
        raise ValueError("concat_batches needs at least one batch")
    out: dict[str, np.ndarray] = {}
    for f in fields(ScenarioBatch):
        arrays = [getattr(b, f.name) for b in batches]
        if f.name in _PADDED:
            width = max(a.shape[1] for a in arrays)
            padded = []
            for a in arrays:
                pad = width - a.shape[1]
                if pad > 0:
                    a = np.concatenate([a, np.full((a.shape[0], pad, *a.shape[2:]), _PADDED[f.name], dtype=a.dtype)],
                                       axis=1)
                padded.append(a)
            arrays = padded
        out[f.name] = np.concatenate(arrays, axis=0)
    return ScenarioBatch(**out)
