"""``compute_metrics``: every per-scenario metric of a batch of planned ego trajectories.

The result is a ``ScenarioMetrics`` of (B,) arrays with stable names; units are in the names
(_s seconds, _m metres, _mps2 m/s^2, _mps3 m/s^3). "*_step" fields index the future axis
(0..F-1, time (step + 1) * dt after t = 0) and "*_nbr" fields the neighbour slots of the batch;
both are -1 when there is no such event. Definitions live in the modules:
``ttc`` (1-D TTC, preceding vehicle), ``ttc2d``, ``pet``, ``drac``, ``distance``, ``collision``,
``kinematics``, ``success``. Infinite values are kept (+inf = no conflict); ``aggregate`` handles them.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import pandas as pd

from letspi.constants import T0_INDEX
from letspi.metrics._common import MetricInputs
from letspi.metrics.collision import collisions
from letspi.metrics.config import MetricsConfig
from letspi.metrics.distance import distances
from letspi.metrics.drac import drac
from letspi.metrics.kinematics import ade_fde, count_lane_changes, finite_difference_kinematics, off_road
from letspi.metrics.pet import pet_grid
from letspi.metrics.success import success
from letspi.metrics.ttc import ttc_1d
from letspi.metrics.ttc2d import ttc_2d
from letspi.scenario.types import ScenarioBatch


@dataclass(frozen=True)
class ScenarioMetrics:
    """Per-scenario metrics, every field (B,).

    Safety (vs the neighbours' ground-truth futures):
        min_ttc_s [s], min_ttc_step, min_ttc_nbr: minimum 1-D TTC with the preceding vehicle.
        low_ttc: min_ttc_s < config.low_ttc_s (2 s).
        min_ttc2d_s [s], min_ttc2d_step, min_ttc2d_nbr: minimum 2-D box TTC over all neighbours.
        min_pet_s [s], min_pet_step, min_pet_nbr: minimum grid PET (+inf undefined); the step is
            when the second vehicle enters the conflict cell.
        max_drac_mps2 [m/s^2], max_drac_step, max_drac_nbr: maximum DRAC (0 never closing, inf overlap).
        min_centre_dist_m [m], min_centre_dist_step, min_centre_dist_nbr: minimum centre distance.
        min_box_gap_m [m], min_gap_step, min_gap_nbr: minimum box-to-box distance (0 = contact).
        collision, collision_step, collision_nbr: box overlap (first step / neighbour).
        collision_2m, collision_2m_step, collision_2m_nbr: the paper's "< 2 m" variant.
    Quality (vs the human ground truth and the road):
        ade_m, fde_m [m]; peak_abs_acc_lon_mps2, peak_abs_acc_lat_mps2, peak_abs_acc_mps2 [m/s^2];
        peak_abs_jerk_mps3 [m/s^3]; n_lane_changes; off_road.
    Success: success and its criteria finite, feasible, goal_reached.
    Rows are in batch order (no scenario id column: the caller holds ``batch.scenario_id``).
    """

    min_ttc_s: np.ndarray
    min_ttc_step: np.ndarray
    min_ttc_nbr: np.ndarray
    low_ttc: np.ndarray
    min_ttc2d_s: np.ndarray
    min_ttc2d_step: np.ndarray
    min_ttc2d_nbr: np.ndarray
    min_pet_s: np.ndarray
    min_pet_step: np.ndarray
    min_pet_nbr: np.ndarray
    max_drac_mps2: np.ndarray
    max_drac_step: np.ndarray
    max_drac_nbr: np.ndarray
    min_centre_dist_m: np.ndarray
    min_centre_dist_step: np.ndarray
    min_centre_dist_nbr: np.ndarray
    min_box_gap_m: np.ndarray
    min_gap_step: np.ndarray
    min_gap_nbr: np.ndarray
    collision: np.ndarray
    collision_step: np.ndarray
    collision_nbr: np.ndarray
    collision_2m: np.ndarray
    collision_2m_step: np.ndarray
    collision_2m_nbr: np.ndarray
    ade_m: np.ndarray
    fde_m: np.ndarray
    peak_abs_acc_lon_mps2: np.ndarray
    peak_abs_acc_lat_mps2: np.ndarray
    peak_abs_acc_mps2: np.ndarray
    peak_abs_jerk_mps3: np.ndarray
    n_lane_changes: np.ndarray
    off_road: np.ndarray
    finite: np.ndarray
    feasible: np.ndarray
    goal_reached: np.ndarray
    success: np.ndarray

    def __len__(self) -> int:
        return len(self.min_ttc_s)

    def to_frame(self) -> pd.DataFrame:
        """One row per scenario (batch order), one column per field (same names and units).

        Scenario ids are not included (callers add ``batch.scenario_id`` as they need).
        """
        return pd.DataFrame({f.name: getattr(self, f.name) for f in fields(self)})

    @classmethod
    def concat(cls, parts: list[ScenarioMetrics]) -> ScenarioMetrics:
        """Concatenate along the scenario axis."""
        return cls(**{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)})


def _compute_chunk(
    batch: ScenarioBatch,
    inp: MetricInputs,
    goals_xy_m: np.ndarray | None,
    config: MetricsConfig,
) -> ScenarioMetrics:
    ttc = ttc_1d(inp)
    t2 = ttc_2d(inp)
    pet = pet_grid(inp, cell_m=config.pet_cell_m, dt_s=config.dt_s)
    dr = drac(inp, ttc.preceding)
    dist = distances(inp)
    coll = collisions(inp, threshold_m=config.collision_2m_m, mode=config.collision_2m_mode)
    ade, fde = ade_fde(inp.ego_xy_m, batch.ego_xy_m[:, batch.future_slice].astype(np.float64))
    kin = finite_difference_kinematics(
        inp.ego_vxy_mps,
        batch.ego_vxy_mps[:, T0_INDEX].astype(np.float64),
        batch.ego_axy_mps2[:, T0_INDEX].astype(np.float64),
        dt_s=config.dt_s,
    )
    marks = batch.marking_y_m.astype(np.float64)
    lane_changes = count_lane_changes(batch.ego_xy_m[:, T0_INDEX, 1].astype(np.float64), inp.ego_xy_m[..., 1], marks)
    offr = off_road(inp.ego_xy_m[..., 1], inp.ego_width_m, marks, batch.marking_is_edge, config.off_road_tol_m)
    ok = success(
        inp.ego_xy_m,
        inp.ego_vxy_mps,
        kin.peak_abs_acc_lon_mps2,
        kin.peak_abs_acc_lat_mps2,
        offr,
        coll.collision,
        coll.collision_2m,
        goals_xy_m,
        config,
    )
    return ScenarioMetrics(
        min_ttc_s=ttc.min_ttc_s,
        min_ttc_step=ttc.min_ttc_step,
        min_ttc_nbr=ttc.min_ttc_nbr,
        low_ttc=ttc.min_ttc_s < config.low_ttc_s,
        min_ttc2d_s=t2.min_ttc2d_s,
        min_ttc2d_step=t2.min_ttc2d_step,
        min_ttc2d_nbr=t2.min_ttc2d_nbr,
        min_pet_s=pet.min_pet_s,
        min_pet_step=pet.min_pet_step,
        min_pet_nbr=pet.min_pet_nbr,
        max_drac_mps2=dr.max_drac_mps2,
        max_drac_step=dr.max_drac_step,
        max_drac_nbr=dr.max_drac_nbr,
        min_centre_dist_m=dist.min_centre_dist_m,
        min_centre_dist_step=dist.min_centre_dist_step,
        min_centre_dist_nbr=dist.min_centre_dist_nbr,
        min_box_gap_m=dist.min_box_gap_m,
        min_gap_step=dist.min_gap_step,
        min_gap_nbr=dist.min_gap_nbr,
        collision=coll.collision,
        collision_step=coll.collision_step,
        collision_nbr=coll.collision_nbr,
        collision_2m=coll.collision_2m,
        collision_2m_step=coll.collision_2m_step,
        collision_2m_nbr=coll.collision_2m_nbr,
        ade_m=ade,
        fde_m=fde,
        peak_abs_acc_lon_mps2=kin.peak_abs_acc_lon_mps2,
        peak_abs_acc_lat_mps2=kin.peak_abs_acc_lat_mps2,
        peak_abs_acc_mps2=kin.peak_abs_acc_mps2,
        peak_abs_jerk_mps3=kin.peak_abs_jerk_mps3,
        n_lane_changes=lane_changes,
        off_road=offr,
        finite=ok.finite,
        feasible=ok.feasible,
        goal_reached=ok.goal_reached,
        success=ok.success,
    )


def compute_metrics(
    batch: ScenarioBatch,
    ego_future_xy_m: np.ndarray,
    ego_future_vxy_mps: np.ndarray,
    goals_xy_m: np.ndarray | None = None,
    config: MetricsConfig | None = None,
) -> ScenarioMetrics:
    """All per-scenario metrics of planned ego futures against the batch's ground truth.

    batch: B scenarios. ego_future_xy_m, ego_future_vxy_mps: (B, F, 2) planned box centres [m]
    and velocities [m/s] in the ego frame for the F = 125 future frames. goals_xy_m: (B, 2) goal
    [m] for the success test, or None to skip the goal criterion. Processed in chunks of
    ``config.chunk_size`` scenarios (vectorised within a chunk) to bound memory.
    """
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
