"""The one registry of per-scenario metrics: each declared once, with how it aggregates.

A ``Metric`` is one column of ``compute_metrics`` (name with unit, dtype, doc, ``source``: ``"group.attribute"`` of
its intermediate results, or None for a column the caller supplies) and the ``Agg`` keys it adds to
``metrics.json``; ``ScenarioMetrics``, the frame, the keys and their reference (``reference_markdown``) derive
from ``METRICS``. Units are in names (_s, _m, _mps2, _mps3, _pct, _n); "*_step" and "*_nbr" columns are -1 for no
event; +inf marks "no conflict"; aggregates never emit NaN or inf.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Literal

from letspi.metrics.config import MetricsConfig
from letspi.metrics.stats import N_RESAMPLES, SEED

AggHow = Literal[
    "finite_mean", "finite_n", "capped_mean", "n_at_or_above", "inf_n", "pct", "pct_below", "pct_above", "pct_equal",
    "pct_mean",
]
Dtype = Literal["float64", "int64", "bool", "str"]

#: aggregations that are a share of scenarios, or a mean over scenarios: the figures that carry a 95 %
#: interval (``letspi.metrics.uncertainty``): Wilson (vehicles) for a share, a bootstrap over ego vehicles for a
#: mean; the others are counts
RATE_HOWS: tuple[str, ...] = ("pct", "pct_below", "pct_above", "pct_equal")
MEAN_HOWS: tuple[str, ...] = ("finite_mean", "capped_mean")

#: what each aggregation does, for the generated documentation
HOW_DOC: MappingProxyType[str, str] = MappingProxyType({
    "finite_mean": "mean of the finite values (None when there are none)",
    "finite_n": "number of finite values",
    "capped_mean": "mean over all scenarios of min(value, {t}); +inf counts as {t}",
    "n_at_or_above": "number of scenarios with value >= {t}",
    "inf_n": "number of infinite values",
    "pct": "share of scenarios where it is True",
    "pct_below": "share of all scenarios with value < {t} (+inf is not below)",
    "pct_above": "share of all scenarios with value > {t} (inf included)",
    "pct_equal": "share of scenarios where it equals {t!r}",
    "pct_mean": "100 x the mean of the finite values (a per-scenario fraction, as a percentage)",
})


@dataclass(frozen=True)
class Agg:
    """One ``metrics.json`` key computed from one per-scenario column; ``threshold``: the cap or threshold of ``how``
    (a ``MetricsConfig`` field name or a number; for ``pct_equal`` the value compared with)."""

    key: str
    how: AggHow
    doc: str = ""
    threshold: str | float | None = None

    def threshold_value(self, config: MetricsConfig) -> str | float | None:
        """The threshold in effect: the config field's value, or the literal."""
        if isinstance(self.threshold, str) and self.how != "pct_equal":
            value: float = getattr(config, self.threshold)
            return value
        return self.threshold

    def unit(self, metric_unit: str) -> str:
        if self.how.startswith("pct"):
            return "%"
        if self.how in ("finite_n", "n_at_or_above", "inf_n"):
            return "count"
        return metric_unit


@dataclass(frozen=True)
class Metric:
    """One per-scenario column: name, unit, dtype, doc, source, aggregations (module doc)."""

    name: str
    unit: str
    dtype: Dtype
    doc: str
    source: str | None
    aggregates: tuple[Agg, ...] = ()


def _step(name: str, of: str, src: str) -> Metric:
    return Metric(name, "step", "int64", f"future step of {of} (-1 none)", src)


def _nbr(name: str, of: str, src: str) -> Metric:
    return Metric(name, "slot", "int64", f"neighbour slot of {of} (-1 none)", src)


def _eq(key: str, kind: str, doc: str) -> Agg:
    return Agg(key, "pct_equal", doc, kind)


METRICS: tuple[Metric, ...] = (
    # --- 1-D TTC, front and rear ------------------------------------------------------------
    Metric("min_ttc_s", "s", "float64",
           "minimum 1-D TTC with the preceding vehicle (ahead, boxes overlapping laterally; "
           "``ttc``); +inf never closing, 0 on overlap", "ttc.min_ttc_s", (
               Agg("ttc_s", "capped_mean", "paper TTC: no closing leader or a harmless TTC counts as "
                   "the cap, so nothing infinite is averaged and nothing is dropped", "ttc_cap_s"),
               Agg("ttc_finite_mean_s", "finite_mean", "uncapped mean over the finite minima"),
               Agg("ttc_finite_n", "finite_n"),
               Agg("ttc_capped_n", "n_at_or_above", "", "ttc_cap_s"),
               Agg("lt_pct", "pct_below", "paper LT (low TTC)", "low_ttc_s"),
           )),
    _step("min_ttc_step", "min_ttc_s", "ttc.min_ttc_step"),
    _nbr("min_ttc_nbr", "min_ttc_s", "ttc.min_ttc_nbr"),
    Metric("low_ttc", "bool", "bool",
           "min_ttc_s < low_ttc_s of the recorded config (``lt_pct`` is re-derived from min_ttc_s "
           "with the aggregation's config)", "route.low_ttc"),
    Metric("min_rear_ttc_s", "s", "float64",
           "minimum 1-D TTC of the following vehicle in the ego's path (mirrored definition, "
           "``ttc``); +inf never closing, 0 on overlap", "rear.min_ttc_s", (
               Agg("rear_ttc_s", "capped_mean", "rear TTC as the paper TTC", "ttc_cap_s"),
               Agg("rear_ttc_finite_mean_s", "finite_mean"),
               Agg("rear_ttc_finite_n", "finite_n"),
               Agg("rear_lt_pct", "pct_below", "low rear TTC", "low_ttc_s"),
           )),
    _step("min_rear_ttc_step", "min_rear_ttc_s", "rear.min_ttc_step"),
    _nbr("min_rear_ttc_nbr", "min_rear_ttc_s", "rear.min_ttc_nbr"),
    # --- 2-D TTC, PET, DRAC ----------------------------------------------------------------------
    Metric("min_ttc2d_s", "s", "float64", "minimum 2-D box TTC over all neighbours (``ttc2d``)",
           "ttc2d.min_ttc2d_s", (Agg("ttc2d_s", "finite_mean"), Agg("ttc2d_finite_n", "finite_n"))),
    _step("min_ttc2d_step", "min_ttc2d_s", "ttc2d.min_ttc2d_step"),
    _nbr("min_ttc2d_nbr", "min_ttc2d_s", "ttc2d.min_ttc2d_nbr"),
    Metric("min_pet_s", "s", "float64",
           "minimum grid PET (cell-centre occupancy, ``pet``); +inf when no shared cell", "pet.min_pet_s", (
               Agg("pet_s", "finite_mean", "paper PET: scenarios without a conflict are left out "
                   "(count in pet_finite_n)"),
               Agg("pet_finite_n", "finite_n"),
               Agg("pet_capped_s", "capped_mean", "PET over all scenarios, no conflict counting as the cap",
                   "pet_cap_s"),
           )),
    Metric("min_pet_step", "step", "int64",
           "future step at which the second vehicle enters the conflict cell (-1 none)", "pet.min_pet_step"),
    _nbr("min_pet_nbr", "min_pet_s", "pet.min_pet_nbr"),
    Metric("max_drac_mps2", "m/s^2", "float64",
           "maximum DRAC towards the preceding vehicle (``drac``); 0 never closing, +inf on overlap",
           "drac.max_drac_mps2", (
               Agg("drac_mps2", "finite_mean", "colliding scenarios (inf) are counted in drac_inf_n"),
               Agg("drac_inf_n", "inf_n"),
               Agg("drac_high_pct", "pct_above", "", "drac_high_mps2"),
           )),
    _step("max_drac_step", "max_drac_mps2", "drac.max_drac_step"),
    _nbr("max_drac_nbr", "max_drac_mps2", "drac.max_drac_nbr"),
    # --- distances ---------------------------------------------------------------------------------
    Metric("min_centre_dist_m", "m", "float64",
           "minimum centre-to-centre distance (the paper's minD magnitude; ``distance``); +inf without "
           "neighbours", "dist.min_centre_dist_m",
           (Agg("min_dist_m", "finite_mean", "paper minD"), Agg("min_dist_finite_n", "finite_n"))),
    _step("min_centre_dist_step", "min_centre_dist_m", "dist.min_centre_dist_step"),
    _nbr("min_centre_dist_nbr", "min_centre_dist_m", "dist.min_centre_dist_nbr"),
    Metric("min_box_gap_m", "m", "float64", "minimum box-to-box distance, the clearance (0 = contact)",
           "dist.min_box_gap_m", (Agg("min_box_gap_m", "finite_mean"), Agg("min_box_gap_finite_n", "finite_n"))),
    _step("min_gap_step", "min_box_gap_m", "dist.min_gap_step"),
    _nbr("min_gap_nbr", "min_box_gap_m", "dist.min_gap_nbr"),
    # --- collisions ------------------------------------------------------------------------------
    Metric("collision", "bool", "bool", "box overlap with any neighbour (real contact; ``collision``)",
           "coll.collision", (Agg("cr_pct", "pct", "paper CR (all contacts, the headline)"),)),
    _step("collision_step", "the first contact", "coll.collision_step"),
    _nbr("collision_nbr", "the first contact", "coll.collision_nbr"),
    Metric("collision_kind", "kind", "str",
           "kind of the first contact: none, front (ego ran into a vehicle ahead), side (came together "
           "laterally), rear (a follower ran into the ego) (``fault``)", "fault.collision_kind", (
               _eq("cr_front_pct", "front", "first contact front"),
               _eq("cr_side_pct", "side", "first contact side"),
               _eq("cr_rear_pct", "rear", "first contact rear"),
           )),
    Metric("collision_at_fault", "bool", "bool",
           "some contact is the ego's fault: front, side with the ego moving laterally, or rear after "
           "braking harder than allowed (``fault``)", "fault.collision_at_fault",
           (Agg("cr_at_fault_pct", "pct", "CR counting only contacts the ego caused"),)),
    _step("collision_fault_step", "the first at-fault contact", "fault.collision_fault_step"),
    _nbr("collision_fault_nbr", "the first at-fault contact", "fault.collision_fault_nbr"),
    Metric("collision_2m", "bool", "bool",
           "the paper's '< 2 m' variant: overlap, or a vehicle in the ego's path closer than 2 m "
           "bumper to bumper (``collision``)", "coll.collision_2m", (Agg("cr2m_pct", "pct"),)),
    _step("collision_2m_step", "the first 2 m event", "coll.collision_2m_step"),
    _nbr("collision_2m_nbr", "the first 2 m event", "coll.collision_2m_nbr"),
    # --- quality ---------------------------------------------------------------------------------
    Metric("ade_m", "m", "float64", "average displacement error to the human future", "route.ade_m",
           (Agg("ade_m", "finite_mean"),)),
    Metric("fde_m", "m", "float64", "final displacement error to the human future", "route.fde_m",
           (Agg("fde_m", "finite_mean"),)),
    Metric("peak_abs_acc_lon_mps2", "m/s^2", "float64", "peak absolute longitudinal acceleration (``kinematics``)",
           "kin.peak_abs_acc_lon_mps2", (Agg("peak_abs_acc_lon_mps2", "finite_mean", "mean of the peaks"),)),
    Metric("peak_abs_acc_lat_mps2", "m/s^2", "float64", "peak absolute lateral acceleration",
           "kin.peak_abs_acc_lat_mps2", (Agg("peak_abs_acc_lat_mps2", "finite_mean", "mean of the peaks"),)),
    Metric("peak_abs_acc_mps2", "m/s^2", "float64", "peak norm of the acceleration", "kin.peak_abs_acc_mps2"),
    Metric("peak_abs_jerk_mps3", "m/s^3", "float64", "peak norm of the jerk", "kin.peak_abs_jerk_mps3",
           (Agg("peak_abs_jerk_mps3", "finite_mean", "mean of the peaks"),)),
    Metric("n_lane_changes", "count", "int64", "lane changes of the planned centre from the t = 0 lane",
           "route.n_lane_changes", (
               Agg("lane_changes_mean", "finite_mean"),
               Agg("lane_change_pct", "pct_above", "at least one lane change", 0.0),
           )),
    Metric("off_road", "bool", "bool", "the ego box leaves the road at some step", "route.off_road",
           (Agg("off_road_pct", "pct"),)),
    # --- success -----------------------------------------------------------------------------------
    Metric("finite", "bool", "bool", "every planned position and velocity is finite", "ok.finite"),
    Metric("feasible", "bool", "bool", "peak accelerations within the feasibility limits", "ok.feasible",
           (Agg("feasible_pct", "pct"),)),
    Metric("reference_reached", "bool", "bool",
           "ends in the recorded human's final lane with the human's progress (``success``)",
           "ok.reference_reached", (Agg("reference_reached_pct", "pct"),)),
    Metric("goal_reached", "bool", "bool", "ends near the planner's own goal (True without a goal)",
           "ok.goal_reached", (Agg("goal_reached_pct", "pct"),)),
    Metric("success", "bool", "bool",
           "finite, feasible, on the road, reference reached, no contact (``success``)", "ok.success",
           (Agg("sr_pct", "pct", "paper SR, against the planner-independent human reference"),)),
    Metric("success_self", "bool", "bool", "as success, but the planner's own goal instead of the reference",
           "ok.success_self", (Agg("sr_self_pct", "pct", "SR against each planner's own goal"),)),
    # --- supplied by the caller ------------------------------------------------------------------
    Metric("inference_s", "s", "float64",
           "planning time per scenario, written by the evaluation harness (or aggregate_metrics' "
           "inference_time_s)", None, (Agg("inference_s", "finite_mean", "paper inference time"),)),
)

#: per-scenario frame columns that record the configuration (not metrics)
CONFIG_COLUMNS: tuple[str, ...] = ("metrics_config_key", "metrics_config")


def computed_metrics() -> tuple[Metric, ...]:
    """The metrics ``compute_metrics`` produces (those with a source)."""
    return tuple(m for m in METRICS if m.source is not None)


def aggregate_keys() -> tuple[str, ...]:
    """Every key of ``aggregate_metrics``' result, in order."""
    return (
        "n",
        *(a.key for m in METRICS for a in m.aggregates),
        "metrics_config_key",
        *MetricsConfig.AGGREGATE_FIELDS,
    )


def reference_markdown() -> str:
    """Markdown reference of the per-scenario columns and the ``metrics.json`` keys."""
    lines = [
        "Per-scenario columns (``compute_metrics(...).to_frame()``; also `scenario_id`, `vehicle_key` (the ego "
        "vehicle: recording content key / ego id), `metrics_config_key` and `metrics_config` (the configuration "
        "as JSON) in the harness's parts):",
        "",
        "| column | unit | dtype | meaning |",
        "|---|---|---|---|",
    ]
    lines += [f"| `{m.name}` | {m.unit} | {m.dtype} | {m.doc} |" for m in METRICS]
    lines += [
        "",
        "Aggregate keys (``aggregate_metrics``, the entries of `metrics.json`); values are float, int, "
        "str or None (None = no scenario had a value; never NaN or inf):",
        "",
        "| key | unit | from | how | 95 % interval |",
        "|---|---|---|---|---|",
        "| `n` | count | | number of scenarios aggregated | |",
    ]
    for m in METRICS:
        for a in m.aggregates:
            how = HOW_DOC[a.how].format(t=a.threshold)
            doc = f"{how}; {a.doc}" if a.doc else how
            interval = "Wilson (vehicles)" if a.how in RATE_HOWS else "vehicle bootstrap" if a.how in MEAN_HOWS else ""
            lines.append(f"| `{a.key}` | {a.unit(m.unit)} | `{m.name}` | {doc} | {interval} |")
    lines.append("| `metrics_config_key` | | | ``MetricsConfig.key()`` of the configuration aggregated with | |")
    lines += [f"| `{f}` | | | the ``MetricsConfig.{f}`` applied | |" for f in MetricsConfig.AGGREGATE_FIELDS]
    lines += [
        "",
        "95 % intervals (`metrics.json` \"intervals\", ``letspi.metrics.uncertainty``) use the per-scenario values "
        "of the key's own definition: Wilson for a share (k of n scenarios) with the effective sample size of "
        "windows grouped by ego vehicle (n / design effect: a vehicle's windows overlap); for a mean a percentile "
        "bootstrap "
        f"({N_RESAMPLES:,} resamples, seed {SEED}) that resamples whole ego vehicles, leaving non-finite values "
        "out as the mean does. Paired comparisons (\"paired\") of the same keys: for shares the windows only one "
        "planner or both have the event with the exact McNemar p, and for every key the vehicle-bootstrap interval "
        "of the per-window difference (means: over the windows where both are finite).",
    ]
    return "\n".join(lines) + "\n"
