"""Aggregation of per-scenario metrics into the paper's Table III (``metrics.json``), and its markdown tables.

Every key comes from ``letspi.metrics.registry.METRICS`` (reference below); values are float, int, str or None
(no finite value; never NaN or inf). Thresholds (``MetricsConfig.AGGREGATE_FIELDS``) apply here, with the config
passed, else the one recorded in the frame (never a silent default); a config differing from the recorded one in a
per-scenario field is refused, as is a frame mixing such configs. The result records ``metrics_config_key``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from letspi.metrics.compute import ScenarioMetrics
from letspi.metrics.config import MetricsConfig
from letspi.metrics.registry import CONFIG_COLUMNS, MEAN_HOWS, METRICS, RATE_HOWS, Agg, reference_markdown
from letspi.metrics.stats import N_RESAMPLES

__doc__ = (__doc__ or "") + reference_markdown()

AggValue = float | int | str | None

#: headline table: the paper's Table III columns, then CR at fault; (label, key)
TABLE_COLUMNS: tuple[tuple[str, str], ...] = (
    ("↑ TTC (s)", "ttc_s"),
    ("↓ CR (%)", "cr_pct"),
    ("↓ CR at fault (%)", "cr_at_fault_pct"),
    ("↑ PET (s)", "pet_s"),
    ("↑ minD (m)", "min_dist_m"),
    ("↓ LT (%)", "lt_pct"),
    ("↑ SR (%)", "sr_pct"),
    ("↓ Inference (s)", "inference_s"),
)

#: safety detail table under the headline: front and rear TTC side by side, collisions by kind
DETAIL_COLUMNS: tuple[tuple[str, str], ...] = (
    ("↑ TTC front (s)", "ttc_s"),
    ("↑ TTC rear (s)", "rear_ttc_s"),
    ("↓ LT rear (%)", "rear_lt_pct"),
    ("↓ CR front (%)", "cr_front_pct"),
    ("↓ CR side (%)", "cr_side_pct"),
    ("↓ CR rear (%)", "cr_rear_pct"),
    ("↑ PET capped (s)", "pet_capped_s"),
    ("↑ SR own goal (%)", "sr_self_pct"),
    ("Shielded (%)", "shielded_pct"),
)


def finite_mean(values: np.ndarray | pd.Series) -> tuple[float | None, int]:
    """Mean of the finite entries and their count; (None, 0) when there are none."""
    v = np.asarray(values, dtype=np.float64)
    ok = np.isfinite(v)
    n = int(ok.sum())
    return (float(v[ok].mean()) if n else None), n


def _pct(flags: np.ndarray) -> float | None:
    return float(100.0 * np.asarray(flags, dtype=bool).mean()) if flags.size else None


def scenario_values(agg: Agg, values: np.ndarray, config: MetricsConfig) -> np.ndarray:
    """The (n,) per-scenario values a rate key (bool; the key is their share) or mean key (float64; the key is the
    mean of the finite entries) averages."""
    t = agg.threshold_value(config)
    if agg.how == "pct_equal":
        return np.asarray(values.astype(str) == str(t))
    if agg.how == "pct":
        return values.astype(bool)
    v = values.astype(np.float64)
    if agg.how == "finite_mean":
        return v
    assert isinstance(t, float | int), agg
    if agg.how == "capped_mean":  # NaN, like +inf, counts as the cap
        return np.fmin(v, t)
    if agg.how == "pct_below":
        return np.asarray(v < t)
    if agg.how == "pct_above":
        return np.asarray(v > t)
    raise ValueError(f"{agg.key}: {agg.how!r} is neither a rate nor a mean")


def apply_agg(agg: Agg, values: np.ndarray, config: MetricsConfig) -> AggValue:
    """One aggregation of one (n,) column (``registry.HOW_DOC``)."""
    if agg.how in RATE_HOWS:
        return _pct(scenario_values(agg, values, config))
    if agg.how in MEAN_HOWS:
        return finite_mean(scenario_values(agg, values, config))[0]
    v = values.astype(np.float64)
    if agg.how == "pct_mean":
        mean = finite_mean(v)[0]
        return None if mean is None else 100.0 * mean
    if agg.how == "finite_n":
        return finite_mean(v)[1]
    if agg.how == "inf_n":
        return int(np.isinf(v).sum())
    t = agg.threshold_value(config)
    assert isinstance(t, float | int), agg
    if agg.how == "n_at_or_above":
        return int((v >= t).sum())
    raise ValueError(f"unknown aggregation {agg.how!r}")


def recorded_config(frame: pd.DataFrame) -> MetricsConfig | None:
    """The ``MetricsConfig`` recorded in a per-scenario frame (None without one; else the first row's); ValueError
    when rows differ in a per-scenario field."""
    column = CONFIG_COLUMNS[1]
    if column not in frame or not len(frame):
        return None
    if frame[column].isna().any():
        raise ValueError(
            f"{int(frame[column].isna().sum())} of {len(frame)} rows record no metrics configuration "
            "(computed by an older letspi?): recompute them"
        )
    texts = pd.unique(frame[column].astype(str))
    configs = [MetricsConfig.from_json(t) for t in texts]
    for other in configs[1:]:
        diff = configs[0].per_scenario_differences(other)
        if diff:
            raise ValueError(
                f"the frame mixes metrics computed with different configurations ({diff}); "
                "aggregate each configuration on its own"
            )
    return configs[0]


def config_in_effect(df: pd.DataFrame, config: MetricsConfig | None) -> MetricsConfig:
    """The configuration to aggregate ``df`` with: ``config``, else the recorded one (module doc)."""
    recorded = recorded_config(df)
    if config is None:
        if recorded is None:
            if len(df):
                raise ValueError(
                    "the frame records no metrics configuration (no 'metrics_config' column): pass "
                    "config=, the MetricsConfig compute_metrics used"
                )
            return MetricsConfig()
        return recorded
    if recorded is not None:
        diff = recorded.per_scenario_differences(config)
        if diff:
            raise ValueError(
                f"these metrics were computed with another configuration; per-scenario fields differ "
                f"(recorded, given): {diff}"
            )
    return config


def aggregate_metrics(
    metrics: ScenarioMetrics | pd.DataFrame,
    inference_time_s: np.ndarray | Sequence[float] | float | None = None,
    config: MetricsConfig | None = None,
) -> dict[str, AggValue]:
    """Aggregate per-scenario metrics (``compute_metrics``' result or its frame; extra columns ignored,
    ``scenario_digest`` must not repeat) into the keys of the module docstring. ``inference_time_s``: planning times
    [s] or one number, None = the frame's ``inference_s``; ``config`` None = the one recorded with the metrics."""
    if isinstance(metrics, ScenarioMetrics):
        df = metrics.to_frame()
        config = config if config is not None else metrics.config
    else:
        df = metrics
    if "scenario_digest" in df and not df["scenario_digest"].is_unique:
        # two writers in one results directory store some scenarios twice: n and every mean would lie
        twice = int(df["scenario_digest"].duplicated().sum())
        raise ValueError(f"{twice} scenario(s) appear more than once in the rows to aggregate (one row per "
                         "scenario digest expected): were two processes writing the same results?")
    cfg = config_in_effect(df, config)
    out: dict[str, AggValue] = {"n": len(df)}
    for m in METRICS:
        if m.name == "inference_s" and inference_time_s is not None:
            values = np.atleast_1d(np.asarray(inference_time_s, dtype=np.float64))  # any length
        elif m.name in df:
            values = df[m.name].to_numpy()
        elif m.source is None:  # a caller-supplied column that is absent
            out.update({a.key: None for a in m.aggregates})
            continue
        else:
            raise KeyError(f"per-scenario column {m.name!r} missing: not a compute_metrics frame of this version")
        for a in m.aggregates:
            out[a.key] = apply_agg(a, values, cfg)
    out["metrics_config_key"] = cfg.key()
    for field in MetricsConfig.AGGREGATE_FIELDS:
        out[field] = float(getattr(cfg, field))
    return out


def _fmt(value: AggValue, digits: int) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, str):
        return value
    if isinstance(value, int | np.integer) and not isinstance(value, bool):
        return str(value)
    if value and abs(float(value)) < 10.0 ** (1 - digits):  # e.g. planning times of 1 ms: 2 significant digits
        return f"{float(value):.{digits}g}"
    return f"{float(value):.{digits}f}"


#: an interval as metrics.json stores it: [low, high], or None when not estimable
StoredInterval = Sequence[float] | None
#: {planner: {key: interval}}: metrics.json's "intervals"
IntervalsByPlanner = Mapping[str, Mapping[str, StoredInterval]]


def format_with_interval(value: AggValue, interval: StoredInterval, digits: int = 2) -> str:
    """``3.67 (2.06–6.45)``, ``-1.62 (-2.91 to -0.16)``: a value and its 95 % interval (if any)."""
    text = _fmt(value, digits)
    if interval is None or value is None or isinstance(value, str) or len(interval) != 2:
        return text
    low, high = float(interval[0]), float(interval[1])
    sep = " to " if low < 0 else "–"  # "-2.91–-0.16" reads badly
    return f"{text} ({_fmt(low, digits)}{sep}{_fmt(high, digits)})"


def _table(
    results: Mapping[str, Mapping[str, AggValue]], columns: tuple[tuple[str, str], ...], digits: int,
    intervals: IntervalsByPlanner | None = None,
) -> list[str]:
    lines = ["| Model | " + " | ".join(label for label, _ in columns) + " |", "|---|" + "---:|" * len(columns)]
    for name, agg in results.items():
        own = (intervals or {}).get(name, {})
        lines.append(f"| {name} | " + " | ".join(format_with_interval(agg.get(key), own.get(key), digits)
                                                 for _, key in columns) + " |")
    return lines


def _p_value(p: object) -> str:
    if not isinstance(p, int | float):
        return "–"
    return "< 0.001" if p < 0.001 else f"{float(p):.3f}"


def paired_rows(paired: Mapping[str, object], columns: tuple[tuple[str, str], ...] = TABLE_COLUMNS,
                digits: int = 2) -> list[list[str]]:
    """Rows (planner, metric, n, Δ with interval, only planner, only reference, both, McNemar p) of
    metrics.json's "paired" entry, per planner and metric of ``columns``; counts and p are "–" for means."""
    planners = paired.get("planners")
    rows: list[list[str]] = []
    for name, keys in (planners.items() if isinstance(planners, Mapping) else ()):
        for label, key in columns:
            rec = keys.get(key) if isinstance(keys, Mapping) else None
            if not isinstance(rec, Mapping):
                continue
            diff = rec.get("diff")
            ci = rec.get("diff_ci95")
            cell = format_with_interval(diff, ci if isinstance(ci, list) and None not in ci else None, digits)
            if isinstance(diff, int | float) and diff > 0:
                cell = "+" + cell
            counts = [str(rec[c]) if c in rec else "–" for c in ("n_only_planner", "n_only_reference", "n_both")]
            p_value = _p_value(rec.get("p_mcnemar"))
            rows.append([str(name), label, str(rec.get("n_pairs", "n/a")), cell, *counts, p_value])
    return rows


def paired_caption(reference: str) -> str:
    """What the paired table shows."""
    return (f"Paired with {reference} (the same windows; Δ = planner − {reference} with its 95 % interval, a "
            "bootstrap over ego vehicles; rates: windows where only the planner, only the reference or both "
            "have the event (for SR: succeed), and the exact McNemar p)")


def render_paired_table(paired: Mapping[str, object], columns: tuple[tuple[str, str], ...] = TABLE_COLUMNS,
                        digits: int = 2) -> list[str]:
    """Markdown lines of metrics.json's "paired" entry (``paired_rows``); empty without comparisons."""
    reference = str(paired.get("reference"))
    rows = paired_rows(paired, columns, digits)
    if not rows:
        return []
    return [paired_caption(reference) + ":", "",
            f"| Model | metric | n | Δ (95 % CI) | only planner | only {reference} | both | p |",
            "|---|---|---:|---:|---:|---:|---:|---:|", *("| " + " | ".join(r) + " |" for r in rows)]


def _num(agg: Mapping[str, AggValue], key: str, default: float) -> str:
    value = agg.get(key)
    return f"{float(value):g}" if isinstance(value, int | float) else f"{default:g}"


def render_markdown_table(results: Mapping[str, Mapping[str, AggValue]], digits: int = 2,
                          intervals: IntervalsByPlanner | None = None,
                          paired: Mapping[str, object] | None = None) -> str:
    """Markdown tables of ``{planner: aggregate_metrics(...)}``: the headline, the safety detail and notes on each
    column (thresholds applied, how many scenarios had a finite TTC / PET)."""
    first: Mapping[str, AggValue] = next(iter(results.values()), {})
    default = MetricsConfig()
    cap = _num(first, "ttc_cap_s", default.ttc_cap_s)
    low = _num(first, "low_ttc_s", default.low_ttc_s)
    pet_cap = _num(first, "pet_cap_s", default.pet_cap_s)
    key = first.get("metrics_config_key", default.key())
    sr_tol = (
        f"within {100 * default.sr_progress_tol_rel:g} %, at least {default.sr_progress_tol_m:g} m"
        if key == default.key()
        else f"tolerances of metrics configuration {key}"
    )
    lines = _table(results, TABLE_COLUMNS, digits, intervals)
    lines += ["", "Safety detail:", "", *_table(results, DETAIL_COLUMNS, digits, intervals), "", "Notes:"]
    lines += [
        f"- TTC: mean over all scenarios of min(minimum 1-D TTC, {cap} s); a scenario without a closing "
        f"vehicle counts as {cap} s. Rear TTC: the same for the vehicle behind in the ego's path. "
        f"LT: minimum TTC below {low} s.",
        "- CR: share of scenarios with box contact (all contacts, the paper's column). CR at fault: only "
        "contacts the ego caused (front; side when the ego moved laterally; rear after braking harder "
        "than allowed).",
        f"- PET: mean over the scenarios with a finite PET (no shared grid cell = no conflict); PET "
        f"capped: mean over all scenarios of min(PET, {pet_cap} s).",
        f"- minD: centre-to-centre distance. SR: feasible, on the road, no contact, and ending in the "
        f"recorded human's final lane with the human's progress ({sr_tol}); SR own goal: the same "
        f"against each planner's own goal.",
    ]
    counts = "; ".join(
        f"{name}: TTC {agg.get('ttc_finite_n', 'n/a')}/{agg.get('n', 'n/a')}, "
        f"PET {agg.get('pet_finite_n', 'n/a')}/{agg.get('n', 'n/a')}"
        for name, agg in results.items()
    )
    lines.append(f"- Scenarios with a finite value (finite/total): {counts}.")
    if intervals:
        lines.append("- In brackets: 95 % intervals; rates (%): Wilson with the effective sample size of windows "
                     "grouped by ego vehicle; means: a bootstrap over ego vehicles (all "
                     f"windows of a vehicle resampled together; {N_RESAMPLES:,} resamples, percentile).")
    keys = {str(agg.get("metrics_config_key")) for agg in results.values()}
    if len(keys) > 1:
        lines.append(
            f"- Warning: the rows were aggregated with different metrics configurations ({', '.join(sorted(keys))})."
        )
    if paired:
        table = render_paired_table(paired, TABLE_COLUMNS, digits)
        lines += ["", *table] if table else []
    return "\n".join(lines) + "\n"
