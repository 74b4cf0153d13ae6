"""Thresholds and tolerances of every metric in one frozen pydantic model (``MetricsConfig``)."""

from __future__ import annotations

import hashlib
import json
from typing import Any, ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field

from letspi.constants import DT_S

Collision2mMode = Literal["longitudinal_gap", "centre_distance", "box_gap"]


class MetricsConfig(BaseModel):
    """Settings of ``compute_metrics`` and ``aggregate_metrics``; SI units. ``key()`` hashes every field but
    ``chunk_size``; per-scenario fields decide stored values, ``AGGREGATE_FIELDS`` apply at aggregation.

    Aggregate (paper Table III): ``low_ttc_s`` (LT: minimum 1-D TTC below it), ``ttc_cap_s`` (the table's TTC
    averages min(TTC, cap)), ``pet_cap_s`` (``pet_capped_s``; default 5 s, the horizon), ``drac_high_mps2``
    (``drac_high_pct``). Per-scenario: ``collision_2m_m`` / ``collision_2m_mode`` (``letspi.metrics.collision``);
    ``pet_cell_m`` (<= 1 m, so every vehicle covers a cell centre across its width); success tolerances
    (``letspi.metrics.success``: ``max_abs_acc_*``, ``off_road_tol_m``, ``success_requires_no_collision_2m``,
    ``sr_*`` against the human endpoint, ``goal_tol_*`` against the planner's goal); at fault
    (``fault_reaction_time_s``, ``fault_comfort_decel_mps2``); ``dt_s``. Reflection (paper §III; independent of the
    evaluation): ``reflection_ttc_s``, ``reflection_min_dist_m``, ``reflection_pet_s`` (None: unused).
    ``chunk_size``: scenarios per vectorised chunk ((B, N, F) float64 temporaries of chunk_size rows)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    #: applied by aggregate_metrics to raw per-scenario values
    AGGREGATE_FIELDS: ClassVar[tuple[str, ...]] = ("low_ttc_s", "ttc_cap_s", "pet_cap_s", "drac_high_mps2")
    #: read by the reflection module only
    REFLECTION_FIELDS: ClassVar[tuple[str, ...]] = ("reflection_ttc_s", "reflection_min_dist_m", "reflection_pet_s")
    #: change no value (left out of ``key()``)
    ENGINEERING_FIELDS: ClassVar[tuple[str, ...]] = ("chunk_size",)

    low_ttc_s: float = Field(default=2.0, gt=0)
    ttc_cap_s: float = Field(default=10.0, gt=0)
    pet_cap_s: float = Field(default=5.0, gt=0)
    drac_high_mps2: float = Field(default=3.0, gt=0)

    collision_2m_m: float = Field(default=2.0, ge=0)
    collision_2m_mode: Collision2mMode = "longitudinal_gap"

    reflection_ttc_s: float = Field(default=1.5, gt=0)
    reflection_min_dist_m: float = Field(default=2.0, ge=0)
    reflection_pet_s: float | None = None

    pet_cell_m: float = Field(default=0.5, gt=0, le=1.0)

    max_abs_acc_lon_mps2: float = Field(default=8.0, gt=0)
    max_abs_acc_lat_mps2: float = Field(default=4.0, gt=0)
    off_road_tol_m: float = Field(default=0.0, ge=0)
    success_requires_no_collision_2m: bool = False
    sr_progress_tol_rel: float = Field(default=0.10, ge=0)
    sr_progress_tol_m: float = Field(default=5.0, ge=0)
    sr_lat_tol_m: float = Field(default=0.5, ge=0)
    goal_tol_lon_m: float = Field(default=5.0, ge=0)
    goal_tol_lat_m: float = Field(default=1.0, ge=0)

    fault_reaction_time_s: float = Field(default=1.0, ge=0)
    fault_comfort_decel_mps2: float = Field(default=3.0, gt=0)

    dt_s: float = Field(default=DT_S, gt=0)
    chunk_size: int = Field(default=1024, ge=1)

    def recorded(self) -> dict[str, Any]:
        """Every field that can change a value (all but ``ENGINEERING_FIELDS``), JSON-ready."""
        return self.model_dump(mode="json", exclude=set(self.ENGINEERING_FIELDS))

    def to_json(self) -> str:
        """Canonical JSON of ``recorded()`` (sorted keys, no spaces): stable across runs."""
        return json.dumps(self.recorded(), sort_keys=True, separators=(",", ":"))

    @classmethod
    def from_json(cls, text: str) -> MetricsConfig:
        """Inverse of ``to_json`` (``chunk_size`` takes its default)."""
        return cls(**json.loads(text))

    def key(self) -> str:
        """Content hash (16 hex digits of SHA-256 of ``to_json()``); equal configs, equal keys."""
        return hashlib.sha256(self.to_json().encode()).hexdigest()[:16]

    def per_scenario_fields(self) -> tuple[str, ...]:
        """Fields that change per-scenario values (neither aggregate, reflection nor engineering)."""
        skip = {*self.AGGREGATE_FIELDS, *self.REFLECTION_FIELDS, *self.ENGINEERING_FIELDS}
        return tuple(name for name in type(self).model_fields if name not in skip)

    def per_scenario_differences(self, other: MetricsConfig) -> dict[str, tuple[Any, Any]]:
        """{field: (self's value, other's value)} for per-scenario fields that differ."""
        return {
            name: (getattr(self, name), getattr(other, name))
            for name in self.per_scenario_fields()
            if getattr(self, name) != getattr(other, name)
        }
