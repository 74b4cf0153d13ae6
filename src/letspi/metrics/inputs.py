"""Shared inputs and helpers of the metrics.

Vehicles are **axis-aligned boxes** in the ego frame (length along x, width along y); headings are ignored. The
future axis F holds frames ``T0_INDEX + 1 ...`` (step f at (f + 1) dt); "step" fields index it and "nbr" fields
the neighbour slots, -1 for none.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from letspi.scenario.types import ScenarioBatch


@dataclass(frozen=True)
class MetricInputs:
    """What every metric needs, float64: ``ego_xy_m``, ``ego_vxy_mps`` (B, F, 2) planned centres and velocities;
    ``ego_length_m``, ``ego_width_m`` (B,); ``nbr_xy_m``, ``nbr_vxy_mps`` (B, N, F, 2) ground-truth futures (NaN where
    invalid), ``nbr_valid`` (B, N, F), ``nbr_length_m``, ``nbr_width_m`` (B, N)."""

    ego_xy_m: np.ndarray
    ego_vxy_mps: np.ndarray
    ego_length_m: np.ndarray
    ego_width_m: np.ndarray
    nbr_xy_m: np.ndarray
    nbr_vxy_mps: np.ndarray
    nbr_valid: np.ndarray
    nbr_length_m: np.ndarray
    nbr_width_m: np.ndarray

    @classmethod
    def from_batch(
        cls, batch: ScenarioBatch, ego_future_xy_m: np.ndarray, ego_future_vxy_mps: np.ndarray
    ) -> MetricInputs:
        """Planned ego future + the batch's neighbour ground truth over ``batch.future_slice``, with the
        batch's context vehicles (``ctx_*``: scored, never shown to planners) appended as slots N..N+C-1."""
        fs = batch.future_slice
        xy = np.asarray(ego_future_xy_m, dtype=np.float64)
        vxy = np.asarray(ego_future_vxy_mps, dtype=np.float64)
        nbr_xy = batch.nbr_xy_m[:, :, fs].astype(np.float64)
        if xy.shape != (len(batch), nbr_xy.shape[2], 2) or vxy.shape != xy.shape:
            raise ValueError(
                f"ego future must be (B, F, 2) = {(len(batch), nbr_xy.shape[2], 2)}, got {xy.shape} / {vxy.shape}"
            )
        return cls(
            ego_xy_m=xy,
            ego_vxy_mps=vxy,
            ego_length_m=batch.ego_length_m.astype(np.float64),
            ego_width_m=batch.ego_width_m.astype(np.float64),
            nbr_xy_m=nbr_xy,
            nbr_vxy_mps=batch.nbr_vxy_mps[:, :, fs].astype(np.float64),
            nbr_valid=batch.nbr_valid[:, :, fs] & np.isfinite(nbr_xy).all(axis=-1),
            nbr_length_m=batch.nbr_length_m.astype(np.float64),
            nbr_width_m=batch.nbr_width_m.astype(np.float64),
        ).with_neighbours(batch.ctx_xy_m, batch.ctx_vxy_mps, batch.ctx_valid, batch.ctx_length_m,
                          batch.ctx_width_m)

    def with_neighbours(
        self,
        xy_m: np.ndarray,
        vxy_mps: np.ndarray,
        valid: np.ndarray,
        length_m: np.ndarray,
        width_m: np.ndarray,
    ) -> MetricInputs:
        """These inputs with K more slots N..N+K-1 (vehicles the plan is checked against): ``xy_m``, ``vxy_mps``
        (B, K, F, 2), ``valid`` (B, K, F), ``length_m``, ``width_m`` (B, K)."""
        xy = np.asarray(xy_m, dtype=np.float64)
        ok = np.asarray(valid, dtype=bool) & np.isfinite(xy).all(axis=-1)
        return MetricInputs(
            ego_xy_m=self.ego_xy_m,
            ego_vxy_mps=self.ego_vxy_mps,
            ego_length_m=self.ego_length_m,
            ego_width_m=self.ego_width_m,
            nbr_xy_m=np.concatenate([self.nbr_xy_m, xy], axis=1),
            nbr_vxy_mps=np.concatenate([self.nbr_vxy_mps, np.asarray(vxy_mps, dtype=np.float64)], axis=1),
            nbr_valid=np.concatenate([self.nbr_valid, ok], axis=1),
            nbr_length_m=np.concatenate([self.nbr_length_m, np.asarray(length_m, dtype=np.float64)], axis=1),
            nbr_width_m=np.concatenate([self.nbr_width_m, np.asarray(width_m, dtype=np.float64)], axis=1),
        )

    def take(self, index: slice | np.ndarray) -> MetricInputs:
        """A sub-batch along B."""
        return MetricInputs(
            **{k: getattr(self, k)[index] for k in self.__dataclass_fields__}  # type: ignore[attr-defined]
        )

    @property
    def n_steps(self) -> int:
        return int(self.ego_xy_m.shape[1])

    # Relative geometry, (B, N, F); cached because several metrics share it ------------------
    @cached_property
    def dx_m(self) -> np.ndarray:
        """Neighbour centre minus ego centre along x, (B, N, F); NaN where invalid."""
        d = self.nbr_xy_m[..., 0] - self.ego_xy_m[:, None, :, 0]
        return np.where(self.nbr_valid, d, np.nan)

    @cached_property
    def dy_m(self) -> np.ndarray:
        """Neighbour centre minus ego centre along y, (B, N, F); NaN where invalid."""
        d = self.nbr_xy_m[..., 1] - self.ego_xy_m[:, None, :, 1]
        return np.where(self.nbr_valid, d, np.nan)

    @cached_property
    def half_len_sum_m(self) -> np.ndarray:
        """(L_ego + L_nbr) / 2, (B, N, 1): centre distance along x at which boxes touch."""
        return (0.5 * (self.ego_length_m[:, None] + self.nbr_length_m))[..., None]

    @cached_property
    def half_wid_sum_m(self) -> np.ndarray:
        """(W_ego + W_nbr) / 2, (B, N, 1): centre distance along y at which boxes touch."""
        return (0.5 * (self.ego_width_m[:, None] + self.nbr_width_m))[..., None]

    @cached_property
    def lateral_overlap(self) -> np.ndarray:
        """Boxes overlap laterally (strictly), (B, N, F) bool; False where invalid."""
        return np.abs(self.dy_m) < self.half_wid_sum_m

    @cached_property
    def longitudinal_overlap(self) -> np.ndarray:
        """Boxes overlap longitudinally (strictly), (B, N, F) bool; False where invalid."""
        return np.abs(self.dx_m) < self.half_len_sum_m


def min_over_nbr_time(values: np.ndarray, *, maximise: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-scenario min (or max) of a (B, N, F) array, NaN ignored, with its step and nbr (B,) each (-1 when all are
    +inf for a min, -inf for a max); ties go to the earliest step, then the lowest slot."""
    b, n, f = values.shape
    fill = -np.inf if maximise else np.inf
    # (B, F, N) order so that argmin's first hit is the earliest step
    flat = np.where(np.isnan(values), fill, values).transpose(0, 2, 1).reshape(b, f * n)
    if flat.shape[1] == 0:
        return np.full(b, fill), np.full(b, -1, np.int64), np.full(b, -1, np.int64)
    idx = flat.argmax(axis=1) if maximise else flat.argmin(axis=1)
    val = np.take_along_axis(flat, idx[:, None], axis=1)[:, 0]
    ok = val != fill
    return val, np.where(ok, idx // n, -1), np.where(ok, idx % n, -1)


def min_over_time(values: np.ndarray, *, maximise: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Per-scenario min (or max) over F of a (B, F) array and its step (-1 when all +inf / -inf)."""
    b, f = values.shape
    fill = -np.inf if maximise else np.inf
    v = np.where(np.isnan(values), fill, values)
    if f == 0:
        return np.full(b, fill), np.full(b, -1, np.int64)
    idx = v.argmax(axis=1) if maximise else v.argmin(axis=1)
    val = np.take_along_axis(v, idx[:, None], axis=1)[:, 0]
    return val, np.where(val != fill, idx, -1)
