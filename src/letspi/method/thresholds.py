"""Safety thresholds of the reflection module (paper §III-E: TTC < 1.5 s or distance < 2.0 m is unsafe).

The paper's "distance" is read as the in-path bumper-to-bumper gap (as ``SafetyCheck.safe`` and ``sf-opt``
read it); contact (box overlap) always violates, whatever the direction.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from letspi.metrics.config import MetricsConfig

#: reflection refinements per scenario (the paper's budget; 0 = the single-shot planner)
MAX_ITERATIONS = 3
#: the evaluation's thresholds (``MetricsConfig.reflection_*``) are the reflection's defaults: one source
_METRICS = MetricsConfig()


class ReflectionThresholds(BaseModel):
    """Thresholds of the reflection loop: minimum front and rear 1-D TTC ``ttc_s`` [s] and in-path gap
    ``min_dist_m`` [m]; ``pet_s`` [s] (None: PET not checked; the paper gives no threshold) on a
    ``pet_cell_m`` grid; ``check_off_road``; ``max_decel_mps2``; ``max_iterations`` refinements after the
    initial proposal (0: the "w/o Ref" ablation)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    ttc_s: float = Field(default=_METRICS.reflection_ttc_s, gt=0)
    min_dist_m: float = Field(default=_METRICS.reflection_min_dist_m, ge=0)
    pet_s: float | None = Field(default=_METRICS.reflection_pet_s, gt=0)
    pet_cell_m: float = Field(default=_METRICS.pet_cell_m, gt=0)
    check_off_road: bool = True
    # not in the paper: the success metric's feasibility bound, so a validated experience is feasible; None: off
    max_decel_mps2: float | None = Field(default=_METRICS.max_abs_acc_lon_mps2, gt=0)
    max_iterations: int = Field(default=MAX_ITERATIONS, ge=0)

    def key(self) -> str:
        """A short stable string for memory configuration keys (``ttc1.5-d2-petnone-it3``)."""
        pet = "none" if self.pet_s is None else f"{self.pet_s:g}"
        road = "" if self.check_off_road else "-noroad"
        brake = "" if self.max_decel_mps2 is None else f"-b{self.max_decel_mps2:g}"
        return f"ttc{self.ttc_s:g}-d{self.min_dist_m:g}-pet{pet}-it{self.max_iterations}{road}{brake}"
