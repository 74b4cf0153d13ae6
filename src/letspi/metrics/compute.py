"""``compute_metrics``: every per-scenario metric (one (B,) array per registry column) of planned ego trajectories
against the batch's ground truth (the neighbours' and ego's recorded futures); +inf (no conflict) is kept.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from operator import attrgetter
from typing import Any

import numpy as np
import pandas as pd

from letspi.constants import T0_INDEX
from letspi.metrics.collision import CollisionResult, collisions
from letspi.metrics.config import MetricsConfig
from letspi.metrics.distance import distances
from letspi.metrics.drac import DRACResult, drac
from letspi.metrics.fault import FaultResult, at_fault_collisions
from letspi.metrics.inputs import MetricInputs
from letspi.metrics.kinematics import (
    KinematicsResult,
    ade_fde,
    count_lane_changes,
    finite_difference_kinematics,
    off_road,
)
from letspi.metrics.pet import pet_grid
from letspi.metrics.registry import CONFIG_COLUMNS, computed_metrics
from letspi.metrics.success import SuccessResult, success
from letspi.metrics.ttc import TTCResult, rear_ttc_1d, ttc_1d
from letspi.metrics.ttc2d import ttc_2d
from letspi.scenario.types import ScenarioBatch


@dataclass(frozen=True)
class _Route:
    """(B,) per-scenario results that are plain arrays (registry group ``route``)."""

    ade_m: np.ndarray
    fde_m: np.ndarray
    n_lane_changes: np.ndarray
    off_road: np.ndarray
    low_ttc: np.ndarray


@dataclass(frozen=True, eq=False)
class ScenarioMetrics:
    """Per-scenario metrics of B scenarios and the ``config`` they were computed with: ``columns``, one (B,) array per
    computed registry metric in registry order and dtype, read as attributes (``m.min_ttc_s``) or items."""

    columns: Mapping[str, np.ndarray]
    config: MetricsConfig

    def __getattr__(self, name: str) -> np.ndarray:
        if name.startswith("__") or name in ("columns", "config"):
            raise AttributeError(name)
        try:
            return self.columns[name]
        except KeyError:
            raise AttributeError(f"{type(self).__name__} has no metric {name!r}") from None

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self.columns)

    def __len__(self) -> int:
        return len(next(iter(self.columns.values()))) if self.columns else 0

    def to_frame(self) -> pd.DataFrame:
        """One row per scenario in batch order: every metric, ``metrics_config_key`` and ``metrics_config`` (JSON)."""
        b = len(self)
        frame = pd.DataFrame(dict(self.columns))
        key, text = CONFIG_COLUMNS
        frame[key] = [self.config.key()] * b
        frame[text] = [self.config.to_json()] * b
        return frame

    @classmethod
    def concat(cls, parts: list[ScenarioMetrics]) -> ScenarioMetrics:
        """Concatenate along the scenario axis (all parts must share one configuration)."""
        if not parts:
            raise ValueError("nothing to concatenate")
        keys = {p.config.key() for p in parts}
        if len(keys) > 1:
            raise ValueError(f"cannot concatenate metrics computed with different configurations {sorted(keys)}")
        names = list(parts[0].columns)
        return cls({k: np.concatenate([p.columns[k] for p in parts]) for k in names}, parts[0].config)


_NUMPY_DTYPES: Mapping[str, Any] = {"float64": np.float64, "int64": np.int64, "bool": np.bool_, "str": object}


def _fault(inp: MetricInputs, coll: CollisionResult, kin: KinematicsResult, dr: DRACResult, ttc: TTCResult,
           config: MetricsConfig) -> FaultResult:
    return at_fault_collisions(inp, coll.overlap, coll.collision_step, coll.collision_nbr, kin.acc_mps2[..., 0],
                               dr.drac_mps2, ttc.preceding.nbr, reaction_time_s=config.fault_reaction_time_s,
                               comfort_decel_mps2=config.fault_comfort_decel_mps2, dt_s=config.dt_s)


def _success(batch: ScenarioBatch, inp: MetricInputs, kin: KinematicsResult, offr: np.ndarray, coll: CollisionResult,
             truth_xy: np.ndarray, goals_xy_m: np.ndarray | None, config: MetricsConfig) -> SuccessResult:
    return success(inp.ego_xy_m, inp.ego_vxy_mps, kin.peak_abs_acc_lon_mps2, kin.peak_abs_acc_lat_mps2, offr,
                   coll.collision, coll.collision_2m, goals_xy_m, config, human_end_xy_m=truth_xy[:, -1],
                   start_x_m=batch.ego_xy_m[:, T0_INDEX, 0].astype(np.float64),
                   marking_y_m=batch.marking_y_m.astype(np.float64))


@dataclass(frozen=True)
class _Core:
    """The groups every outcome needs (shared by ``compute_metrics`` and ``compute_outcomes``)."""

    ttc: TTCResult
    dr: DRACResult
    coll: CollisionResult
    kin: KinematicsResult
    offr: np.ndarray
    truth_xy: np.ndarray
    fault: FaultResult
    ok: SuccessResult


def _core(batch: ScenarioBatch, inp: MetricInputs, goals_xy_m: np.ndarray | None, config: MetricsConfig) -> _Core:
    ttc = ttc_1d(inp)
    dr = drac(inp, ttc.preceding)
    coll = collisions(inp, threshold_m=config.collision_2m_m, mode=config.collision_2m_mode)
    truth_xy = batch.ego_xy_m[:, batch.future_slice].astype(np.float64)
    kin = finite_difference_kinematics(
        inp.ego_vxy_mps,
        batch.ego_vxy_mps[:, T0_INDEX].astype(np.float64),
        batch.ego_axy_mps2[:, T0_INDEX].astype(np.float64),
        dt_s=config.dt_s,
    )
    marks = batch.marking_y_m.astype(np.float64)
    offr = off_road(inp.ego_xy_m[..., 1], inp.ego_width_m, marks, batch.marking_is_edge, config.off_road_tol_m)
    return _Core(ttc=ttc, dr=dr, coll=coll, kin=kin, offr=offr, truth_xy=truth_xy,
                 fault=_fault(inp, coll, kin, dr, ttc, config),
                 ok=_success(batch, inp, kin, offr, coll, truth_xy, goals_xy_m, config))


def _compute_chunk(
    batch: ScenarioBatch,
    inp: MetricInputs,
    goals_xy_m: np.ndarray | None,
    config: MetricsConfig,
) -> ScenarioMetrics:
    core = _core(batch, inp, goals_xy_m, config)
    ade, fde = ade_fde(inp.ego_xy_m, core.truth_xy)
    marks = batch.marking_y_m.astype(np.float64)
    y0 = batch.ego_xy_m[:, T0_INDEX, 1].astype(np.float64)
    groups: dict[str, Any] = {
        "ttc": core.ttc,
        "rear": rear_ttc_1d(inp),
        "ttc2d": ttc_2d(inp),
        "pet": pet_grid(inp, cell_m=config.pet_cell_m, dt_s=config.dt_s),
        "drac": core.dr,
        "dist": distances(inp),
        "coll": core.coll,
        "fault": core.fault,
        "kin": core.kin,
        "route": _Route(
            ade_m=ade,
            fde_m=fde,
            n_lane_changes=count_lane_changes(y0, inp.ego_xy_m[..., 1], marks),
            off_road=core.offr,
            low_ttc=core.ttc.min_ttc_s < config.low_ttc_s,
        ),
        "ok": core.ok,
    }
    columns: dict[str, np.ndarray] = {}
    for m in computed_metrics():
        group, attr = str(m.source).split(".", 1)
        columns[m.name] = np.asarray(attrgetter(attr)(groups[group]), dtype=_NUMPY_DTYPES[m.dtype])
    return ScenarioMetrics(columns, config)


@dataclass(frozen=True)
class PlanOutcomes:
    """(B,) each: ``compute_metrics``' ``collision``, ``collision_at_fault``, ``success``, ``min_ttc_s``, and
    ``progress_m``, the plan's final x [m]."""

    collision: np.ndarray
    collision_at_fault: np.ndarray
    success: np.ndarray
    min_ttc_s: np.ndarray
    progress_m: np.ndarray


def compute_outcomes(
    batch: ScenarioBatch,
    ego_future_xy_m: np.ndarray,
    ego_future_vxy_mps: np.ndarray,
    config: MetricsConfig | None = None,
) -> PlanOutcomes:
    """``PlanOutcomes`` of planned ego futures (B, F, 2) against the batch's ground truth: the subset of
    ``compute_metrics``, computing only what it needs, chunked alike."""
    cfg = config if config is not None else MetricsConfig()
    xy = np.asarray(ego_future_xy_m, dtype=np.float64)
    vxy = np.asarray(ego_future_vxy_mps, dtype=np.float64)
    parts: list[tuple[np.ndarray, ...]] = []
    for start in range(0, max(len(batch), 1), cfg.chunk_size):
        sl = slice(start, min(start + cfg.chunk_size, len(batch)))
        sub = batch.take(sl)
        inp = MetricInputs.from_batch(sub, xy[sl], vxy[sl])
        core = _core(sub, inp, None, cfg)
        parts.append((core.coll.collision, core.fault.collision_at_fault, core.ok.success, core.ttc.min_ttc_s,
                      xy[sl, -1, 0] if xy.shape[1] else np.zeros(len(sub))))
    cols = [np.concatenate([p[k] for p in parts]) for k in range(5)]
    return PlanOutcomes(collision=cols[0].astype(bool), collision_at_fault=cols[1].astype(bool),
                        success=cols[2].astype(bool), min_ttc_s=cols[3].astype(np.float64),
                        progress_m=cols[4].astype(np.float64))


def compute_metrics(
    batch: ScenarioBatch,
    ego_future_xy_m: np.ndarray,
    ego_future_vxy_mps: np.ndarray,
    goals_xy_m: np.ndarray | None = None,
    config: MetricsConfig | None = None,
) -> ScenarioMetrics:
    """All per-scenario metrics of planned ego futures (B, F, 2) centres [m] and velocities [m/s], ego frame.
    ``goals_xy_m``: (B, 2) the planner's own goal for ``success_self``, or None (that criterion holds); ``success`` is
    judged against the human either way. Computed in chunks of ``config.chunk_size`` scenarios."""
    cfg = config if config is not None else MetricsConfig()
    xy = np.asarray(ego_future_xy_m, dtype=np.float64)
    vxy = np.asarray(ego_future_vxy_mps, dtype=np.float64)
    goals = None if goals_xy_m is None else np.asarray(goals_xy_m, dtype=np.float64)
    if goals is not None and goals.shape != (len(batch), 2):
        raise ValueError(f"goals_xy_m must be (B, 2) = ({len(batch)}, 2), got {goals.shape}")
    parts = []
    for start in range(0, len(batch), cfg.chunk_size):
        sl = slice(start, min(start + cfg.chunk_size, len(batch)))
        sub = batch.take(sl)
        inp = MetricInputs.from_batch(sub, xy[sl], vxy[sl])
        parts.append(_compute_chunk(sub, inp, None if goals is None else goals[sl], cfg))
    if not parts:
        empty = MetricInputs.from_batch(batch, xy, vxy)
        return _compute_chunk(batch, empty, goals, cfg)
    return parts[0] if len(parts) == 1 else ScenarioMetrics.concat(parts)


def human_future(batch: ScenarioBatch) -> tuple[np.ndarray, np.ndarray]:
    """The ground-truth ego future (B, F, 2) positions and velocities: the "human planner"."""
    fs = batch.future_slice
    return batch.ego_xy_m[:, fs].astype(np.float64), batch.ego_vxy_mps[:, fs].astype(np.float64)
