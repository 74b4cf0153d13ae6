"""Thresholds and tolerances of every metric in one pydantic model (``MetricsConfig``)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from letspi.constants import DT_S

Collision2mMode = Literal["longitudinal_gap", "centre_distance", "box_gap"]


class MetricsConfig(BaseModel):
    """Settings of ``compute_metrics`` and ``aggregate_metrics``. SI units throughout.

    Evaluation thresholds (paper Table III):
        low_ttc_s: a scenario is "low TTC" (LT) when its minimum 1-D TTC is below this [s].
        ttc_cap_s: the table's TTC averages min(TTC, ttc_cap_s) over all scenarios [s].
        collision_2m_m / collision_2m_mode: the paper's "distance < 2.0 m" collision variant
            (``collision_2m``); see ``letspi.metrics.collision`` for the three readings.
    Reflection thresholds (paper §III, reflection module; kept here so the reflection module and
    the evaluation read one source, but independent of the evaluation thresholds above):
        reflection_ttc_s (1.5 s), reflection_min_dist_m (2.0 m; which distance it applies to is
        the reflection module's choice, see ``letspi.metrics.collision`` for the trade-offs),
        reflection_pet_s (None = PET not used by reflection).
    PET: pet_cell_m, the grid cell size [m] (0.5-1 m is the usual range).
    Success (see ``letspi.metrics.success``): max_abs_acc_lon_mps2, max_abs_acc_lat_mps2,
        goal_tol_lon_m, goal_tol_lat_m, off_road_tol_m, success_requires_no_collision_2m.
    Engineering: dt_s (time step of the future), chunk_size (scenarios per vectorised chunk,
        bounds memory: the (B, N, F) temporaries are chunk_size x 8 x 125 float64).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    low_ttc_s: float = Field(default=2.0, gt=0)
    ttc_cap_s: float = Field(default=10.0, gt=0)
    collision_2m_m: float = Field(default=2.0, ge=0)
    collision_2m_mode: Collision2mMode = "longitudinal_gap"

    reflection_ttc_s: float = Field(default=1.5, gt=0)
    reflection_min_dist_m: float = Field(default=2.0, ge=0)
    reflection_pet_s: float | None = None

    pet_cell_m: float = Field(default=0.5, gt=0)

    max_abs_acc_lon_mps2: float = Field(default=8.0, gt=0)
    max_abs_acc_lat_mps2: float = Field(default=4.0, gt=0)
    goal_tol_lon_m: float = Field(default=5.0, ge=0)
    goal_tol_lat_m: float = Field(default=1.0, ge=0)
    off_road_tol_m: float = Field(default=0.0, ge=0)
    success_requires_no_collision_2m: bool = False

    dt_s: float = Field(default=DT_S, gt=0)
    chunk_size: int = Field(default=1024, ge=1)
