"""Aggregation of per-scenario metrics into the paper's Table III, and its markdown rendering.

Contract of the aggregated dict (also the schema of ``metrics.json``); values are float, int, or
None (None = no scenario had a finite value; NaN and inf are never emitted):

Paper columns
    n             int  number of scenarios aggregated.
    ttc_s         s    mean over ALL n scenarios of min(minimum 1-D TTC, ``ttc_cap_s``) (10 s by
                       default): a scenario with no closing leader (+inf) or a harmless TTC above
                       the cap counts as the cap, so no inf is averaged, none is dropped, and a few
                       near-zero closing speeds (TTC of hundreds of seconds) can't swamp the mean.
                       ``ttc_finite_n`` counts scenarios with a finite minimum, ``ttc_capped_n``
                       those at or above the cap; ``ttc_finite_mean_s`` is the uncapped mean
                       over the finite ones.
    cr_pct        %    share of scenarios with a box-overlap collision (``collision``).
    pet_s         s    mean of the finite per-scenario minimum grid PET; count in ``pet_finite_n``.
    min_dist_m    m    mean of the per-scenario minimum **centre-to-centre** distance (the paper's
                       minD magnitude, 13-18 m); scenarios without any neighbour are left out
                       (count ``min_dist_finite_n``). See ``min_box_gap_m`` for the clearance.
    lt_pct        %    share of all n scenarios whose minimum TTC is below ``low_ttc_s`` (2 s);
                       +inf counts as not low.
    sr_pct        %    share of scenarios with ``success`` (``letspi.metrics.success``).
    inference_s   s    mean planning time per scenario: from ``inference_time_s`` if given, else
                       from an ``inference_s`` column of the frame, else None.
Extras
    ttc_finite_n, pet_finite_n, min_dist_finite_n, ttc2d_finite_n, min_box_gap_finite_n  int
    ttc2d_s       s    mean of the finite minimum 2-D TTC.
    drac_mps2     m/s^2 mean of the finite per-scenario maximum DRAC (0 when never closing;
                       colliding scenarios have inf and are counted in ``drac_inf_n``).
    drac_high_pct %    share with maximum DRAC > 3 m/s^2 (SUMO's threshold; inf included).
    min_box_gap_m m    mean of the per-scenario minimum box-to-box distance (0 = contact).
    cr2m_pct      %    share with the "distance < 2 m" collision variant (``collision_2m``).
    ade_m, fde_m  m    mean displacement errors to the human future (finite values only).
    peak_abs_acc_lon_mps2, peak_abs_acc_lat_mps2 m/s^2, peak_abs_jerk_mps3 m/s^3: means of the
                       per-scenario peaks (finite values only).
    lane_changes_mean  mean number of lane changes; lane_change_pct % with at least one.
    off_road_pct, feasible_pct, goal_reached_pct  %  shares of the success criteria.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from letspi.metrics.config import MetricsConfig
from letspi.metrics.evaluate import ScenarioMetrics

AggValue = float | int | None

#: paper column label -> (key, higher is better)
TABLE_COLUMNS: tuple[tuple[str, str], ...] = (
    ("↑ TTC (s)", "ttc_s"),
    ("↓ CR (%)", "cr_pct"),
    ("↑ PET (s)", "pet_s"),
    ("↑ minD (m)", "min_dist_m"),
    ("↓ LT (%)", "lt_pct"),
    ("↑ SR (%)", "sr_pct"),
    ("↓ Inference (s)", "inference_s"),
)


def finite_mean(values: np.ndarray | pd.Series) -> tuple[float | None, int]:
    """Mean of the finite entries and their count; (None, 0) when there are none."""
    v = np.asarray(values, dtype=np.float64)
    ok = np.isfinite(v)
    n = int(ok.sum())
    return (float(v[ok].mean()) if n else None), n


def _pct(flags: np.ndarray | pd.Series) -> float | None:
    f = np.asarray(flags, dtype=bool)
    return float(100.0 * f.mean()) if f.size else None


def aggregate_metrics(
    metrics: ScenarioMetrics | pd.DataFrame,
    inference_time_s: np.ndarray | Sequence[float] | float | None = None,
    config: MetricsConfig | None = None,
) -> dict[str, AggValue]:
    """Aggregate per-scenario metrics into the contract above (module doc).

    inference_time_s: per-scenario planning times [s] (their mean is reported) or one number;
    when None, a per-scenario ``inference_s`` column of a DataFrame input is used if present.
    ``config`` supplies ``ttc_cap_s``; ``low_ttc`` was already decided by ``compute_metrics``.
    """
    config = config or MetricsConfig()
    df = metrics.to_frame() if isinstance(metrics, ScenarioMetrics) else metrics
    out: dict[str, AggValue] = {"n": len(df)}
    min_ttc = np.asarray(df["min_ttc_s"], dtype=np.float64)
    out["ttc_s"] = float(np.minimum(min_ttc, config.ttc_cap_s).mean()) if len(min_ttc) else None
    out["ttc_finite_mean_s"], out["ttc_finite_n"] = finite_mean(min_ttc)
    out["ttc_capped_n"] = int((min_ttc >= config.ttc_cap_s).sum())
    out["cr_pct"] = _pct(df["collision"])
    out["pet_s"], out["pet_finite_n"] = finite_mean(df["min_pet_s"])
    out["min_dist_m"], out["min_dist_finite_n"] = finite_mean(df["min_centre_dist_m"])
    out["lt_pct"] = _pct(df["low_ttc"])
    out["sr_pct"] = _pct(df["success"])
    if inference_time_s is None and "inference_s" in df:
        inference_time_s = np.asarray(df["inference_s"], dtype=np.float64)
    if inference_time_s is None:
        out["inference_s"] = None
    else:
        out["inference_s"], _ = finite_mean(np.atleast_1d(np.asarray(inference_time_s, dtype=np.float64)))
    out["ttc2d_s"], out["ttc2d_finite_n"] = finite_mean(df["min_ttc2d_s"])
    drac = np.asarray(df["max_drac_mps2"], dtype=np.float64)
    out["drac_mps2"], _ = finite_mean(drac)
    out["drac_inf_n"] = int(np.isinf(drac).sum())
    out["drac_high_pct"] = _pct(drac > 3.0)
    out["min_box_gap_m"], out["min_box_gap_finite_n"] = finite_mean(df["min_box_gap_m"])
    out["cr2m_pct"] = _pct(df["collision_2m"])
    out["ade_m"], _ = finite_mean(df["ade_m"])
    out["fde_m"], _ = finite_mean(df["fde_m"])
    for key in ("peak_abs_acc_lon_mps2", "peak_abs_acc_lat_mps2", "peak_abs_jerk_mps3"):
        out[key], _ = finite_mean(df[key])
    lc = np.asarray(df["n_lane_changes"], dtype=np.float64)
    out["lane_changes_mean"], _ = finite_mean(lc)
    out["lane_change_pct"] = _pct(lc > 0)
    out["off_road_pct"] = _pct(df["off_road"])
    out["feasible_pct"] = _pct(df["feasible"])
    out["goal_reached_pct"] = _pct(df["goal_reached"])
    return out


def _fmt(value: AggValue, digits: int) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, int | np.integer) and not isinstance(value, bool):
        return str(value)
    return f"{float(value):.{digits}f}"


def render_markdown_table(results: Mapping[str, Mapping[str, AggValue]], digits: int = 2) -> str:
    """Paper-style markdown table (one row per planner) from ``{planner: aggregate_metrics(...)}``.

    A note under the table gives, per planner, how many scenarios had a finite TTC / PET, so
    infinite values are never silently dropped.
    """
    header = "| Model | " + " | ".join(label for label, _ in TABLE_COLUMNS) + " |"
    rule = "|---|" + "---:|" * len(TABLE_COLUMNS)
    lines = [header, rule]
    for name, agg in results.items():
        cells = [_fmt(agg.get(key), digits) for _, key in TABLE_COLUMNS]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    notes = [
        f"{name}: TTC {agg.get('ttc_finite_n', 'n/a')}/{agg.get('n', 'n/a')}, "
        f"PET {agg.get('pet_finite_n', 'n/a')}/{agg.get('n', 'n/a')}"
        for name, agg in results.items()
    ]
    lines.append("")
    lines.append(
        "TTC: mean over all scenarios of min(TTC, cap), no closing leader counting as the cap "
        "(finite minimum TTC / total, and PET: mean over scenarios with a finite PET, finite/total: "
        + "; ".join(notes)
        + "). minD is the centre-to-centre distance."
    )
    return "\n".join(lines) + "\n"
