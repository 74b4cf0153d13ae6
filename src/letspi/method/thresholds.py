"""Safety thresholds of the reflection module (paper §III-E: TTC < 1.5 s or distance < 2.0 m is unsafe).

Reading of the paper's "minimum distance < 2.0 m" (the same one ``letspi.safety.plan_check.SafetyCheck.safe``
and ``sf-opt`` use, so a plan the reflection accepts is one sf-opt would accept too):

* ``min_dist_m`` applies to the **in-path gap**: the bumper-to-bumper distance to a vehicle whose box
  overlaps the ego's laterally (ahead or behind). An ordinary adjacent-lane pass leaves ~1.9 m between
  boxes on 3.75 m lanes; applying 2 m to the raw box gap would flag every one of them.
* **Contact** (the boxes overlap, box gap 0 < ``min_dist_m``) is always a violation, whatever the
  direction, so a side-swipe during a lane change is caught even though it is not "in path" beforehand.
* Front and rear 1-D TTC below ``ttc_s`` and leaving the road are violations; PET only when ``pet_s`` is set.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from letspi.metrics.config import MetricsConfig

#: reflection refinements per scenario (the paper's budget; 0 = the single-shot planner)
MAX_ITERATIONS = 3
#: the evaluation's thresholds (``MetricsConfig.reflection_*``) are the reflection's defaults: one source
_METRICS = MetricsConfig()


class ReflectionThresholds(BaseModel):
    """Thresholds [SI] and the iteration budget of the reflection loop.

    ttc_s: minimum acceptable front and rear 1-D TTC [s].
    min_dist_m: minimum acceptable in-path bumper-to-bumper gap [m]; contact always violates.
    pet_s: minimum acceptable post-encroachment time [s]; None = PET not checked (the paper lists PET
        among the reflection metrics without a threshold).
    pet_cell_m: grid cell of the PET computation [m].
    check_off_road: leaving the road (box beyond a road edge) is a violation.
    max_iterations: refinement rounds after the initial proposal, so at most ``max_iterations + 1``
        proposals; 0 disables refinement (the "w/o Ref" ablation).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    ttc_s: float = Field(default=_METRICS.reflection_ttc_s, gt=0)
    min_dist_m: float = Field(default=_METRICS.reflection_min_dist_m, ge=0)
    pet_s: float | None = Field(default=_METRICS.reflection_pet_s, gt=0)
    pet_cell_m: float = Field(default=_METRICS.pet_cell_m, gt=0)
    check_off_road: bool = True
    # not in the paper: a plan braking harder than this is not "validated" either; 8 m/s^2 is the
    # feasibility bound of the success metric (MetricsConfig.max_abs_acc_lon_mps2), so a validated
    # experience is also a feasible one; None disables the check
    max_decel_mps2: float | None = Field(default=_METRICS.max_abs_acc_lon_mps2, gt=0)
    max_iterations: int = Field(default=MAX_ITERATIONS, ge=0)

    def key(self) -> str:
        """A short stable string for memory configuration keys (``ttc1.5-d2-petnone-it3``)."""
        pet = "none" if self.pet_s is None else f"{self.pet_s:g}"
        road = "" if self.check_off_road else "-noroad"
        brake = "" if self.max_decel_mps2 is None else f"-b{self.max_decel_mps2:g}"
        return f"ttc{self.ttc_s:g}-d{self.min_dist_m:g}-pet{pet}-it{self.max_iterations}{road}{brake}"
