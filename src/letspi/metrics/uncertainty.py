"""Intervals and paired comparisons of the aggregated metrics: ``metrics.json``'s "intervals" and "paired".

Each rate or mean key's interval and paired difference come from exactly the per-scenario values it averages
(``aggregate.scenario_values``), with the statistics of ``letspi.metrics.stats``; counts (``*_n``) get none.
The frames need a ``vehicle_key`` column and, to be paired, ``scenario_digest``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import pandas as pd

from letspi.metrics.aggregate import config_in_effect, scenario_values
from letspi.metrics.config import MetricsConfig
from letspi.metrics.registry import MEAN_HOWS, METRICS, RATE_HOWS
from letspi.metrics.stats import (
    LEVEL,
    N_RESAMPLES,
    SEED,
    bootstrap_mean_intervals,
    design_effect,
    group_index,
    paired_comparisons,
    rounded,
    vehicle_wilson_interval,
)

#: the per-row column holding the group of the vehicle bootstrap
GROUP_COLUMN = "vehicle_key"
#: how the interval of each kind of key is made ("statistics.interval_methods" of metrics.json)
METHODS: Mapping[str, str] = {"rate": "vehicle-wilson", "mean": "vehicle-bootstrap"}

StatKind = Literal["rate", "mean"]
JsonInterval = list[float] | None


@dataclass(frozen=True)
class Statistic:
    """The per-scenario values behind one key: (n,) bool for a rate, float64 for a mean (of the finite entries)."""

    key: str
    kind: StatKind
    values: np.ndarray

    @property
    def method(self) -> str:
        return METHODS[self.kind]


def rate_statistic(key: str, flags: np.ndarray | pd.Series) -> Statistic:
    """A rate key from (n,) 0/1 flags (bool or 0.0/1.0; anything else is refused)."""
    v = np.asarray(flags)
    if v.dtype != bool:
        f = v.astype(np.float64)
        if not np.isin(f, (0.0, 1.0)).all():
            raise ValueError(f"{key}: a rate needs 0/1 flags per scenario")
        v = f > 0.5
    return Statistic(key, "rate", v)


def metric_statistics(frame: pd.DataFrame, config: MetricsConfig | None = None) -> dict[str, Statistic]:
    """The rate and mean keys of ``aggregate_metrics`` with their per-scenario values, for the columns
    present in ``frame`` (``inference_s``: the frame's column; pass NaN for rows not to be timed)."""
    cfg = config_in_effect(frame, config)
    out: dict[str, Statistic] = {}
    for m in METRICS:
        if m.name not in frame:
            continue
        column = frame[m.name].to_numpy()
        for a in m.aggregates:
            if a.how in RATE_HOWS:
                out[a.key] = Statistic(a.key, "rate", scenario_values(a, column, cfg))
            elif a.how in MEAN_HOWS:
                out[a.key] = Statistic(a.key, "mean", scenario_values(a, column, cfg))
    return out


def _json_interval(low: float, high: float) -> JsonInterval:
    return [low, high] if np.isfinite(low) and np.isfinite(high) else None


def _buckets(groups: Mapping[str, np.ndarray]) -> list[list[str]]:
    """Names whose (n,) group arrays are equal, together: their columns can share one set of resamples."""
    buckets: list[list[str]] = []
    for name, g in groups.items():
        for bucket in buckets:
            if np.array_equal(groups[bucket[0]], g):
                bucket.append(name)
                break
        else:
            buckets.append([name])
    return buckets


def intervals_of(subjects: Mapping[str, tuple[Mapping[str, Statistic], np.ndarray]], level: float = LEVEL,
                 n_resamples: int = N_RESAMPLES, seed: int = SEED) -> dict[str, dict[str, JsonInterval]]:
    """``intervals`` of several planners, {name: (statistics, groups)} -> {name: {key: interval}}; planners
    holding the same windows share one bootstrap call."""
    out: dict[str, dict[str, JsonInterval]] = {name: {} for name in subjects}
    for bucket in _buckets({name: g for name, (_, g) in subjects.items()}):
        means = [(name, st) for name in bucket for st in subjects[name][0].values() if st.kind == "mean"]
        if means:
            ends = bootstrap_mean_intervals(np.stack([st.values for _, st in means], axis=1), subjects[bucket[0]][1],
                                            level, n_resamples, seed)
            for (name, st), (lo, hi) in zip(means, ends, strict=True):
                out[name][st.key] = _json_interval(float(lo), float(hi))
    for name, (stats, groups) in subjects.items():
        for st in stats.values():
            if st.kind == "rate":
                lo, hi = vehicle_wilson_interval(st.values, groups, level)
                out[name][st.key] = _json_interval(rounded(100.0 * lo), rounded(100.0 * hi))
        out[name] = {key: out[name][key] for key in stats}
    return out


def intervals(statistics: Mapping[str, Statistic], groups: np.ndarray, level: float = LEVEL,
              n_resamples: int = N_RESAMPLES, seed: int = SEED) -> dict[str, JsonInterval]:
    """Key -> [low, high] (percent for rates, the key's unit for means), None when not estimable (no scenario; a
    mean with fewer than 2 vehicles holding a finite value). ``groups``: (n,) vehicle of each row."""
    return intervals_of({"": (statistics, groups)}, level, n_resamples, seed)[""]


PairSubject = tuple[Mapping[str, Statistic], Mapping[str, Statistic], np.ndarray]


def paired_of(subjects: Mapping[str, PairSubject], level: float = LEVEL, n_resamples: int = N_RESAMPLES,
              seed: int = SEED) -> dict[str, dict[str, dict[str, Any]]]:
    """``paired`` of several planners, {name: (planner statistics, reference statistics, groups)} ->
    {name: {key: record}}; planners holding the same windows share one bootstrap call."""
    out: dict[str, dict[str, dict[str, Any]]] = {name: {} for name in subjects}
    for bucket in _buckets({name: g for name, (_, _, g) in subjects.items()}):
        keys = [(name, k) for name in bucket for k, a in subjects[name][0].items()
                if k in subjects[name][1] and subjects[name][1][k].kind == a.kind]
        pairs = [(subjects[n][0][k].kind, subjects[n][0][k].values, subjects[n][1][k].values) for n, k in keys]
        results = paired_comparisons(pairs, subjects[bucket[0]][2], level, n_resamples, seed)
        for (name, k), r in zip(keys, results, strict=True):
            out[name][k] = r.record()
    return out


def paired(planner: Mapping[str, Statistic], reference: Mapping[str, Statistic], groups: np.ndarray,
           level: float = LEVEL, n_resamples: int = N_RESAMPLES, seed: int = SEED) -> dict[str, dict[str, Any]]:
    """Key -> the paired record (``PairedRate`` / ``PairedMean`` ``.record()``) of the planner against the
    reference, for the keys both have; row i of every statistic is the same window."""
    return paired_of({"": (planner, reference, groups)}, level, n_resamples, seed)[""]


def statistics_record(level: float = LEVEL, n_resamples: int = N_RESAMPLES, seed: int = SEED,
                      keys: Mapping[str, Statistic] | None = None) -> dict[str, Any]:
    """The "statistics" entry of ``metrics.json``: level, bootstrap settings and the method per key."""
    return {"level": level,
            "interval_methods": {k: s.method for k, s in (keys or {}).items()},
            "bootstrap": {"resamples": n_resamples, "seed": seed, "groups": "ego vehicle (recording, ego id)",
                          "interval": "percentile"},
            "wilson": "effective sample size n / design effect of the windows grouped by ego vehicle "
                      "(design_effects; 1 = independent windows)",
            "paired": "rates: exact McNemar p of the discordant windows; every difference: vehicle-bootstrap "
                      "interval of the per-window difference (means: windows where both are finite)"}


def design_effects(statistics: Mapping[str, Statistic], groups: np.ndarray) -> dict[str, float]:
    """Rate key -> its ``design_effect`` (how much the vehicles' grouping widens its interval, squared)."""
    return {k: round(design_effect(st.values, groups), 3) for k, st in statistics.items() if st.kind == "rate"}


def n_groups(groups: np.ndarray) -> int:
    """Number of distinct vehicles among ``groups``."""
    return group_index(groups)[1]


def align(frame_a: pd.DataFrame, frame_b: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The rows of both frames for the scenario digests they share, in ``frame_a``'s order."""
    shared = frame_a["scenario_digest"].isin(set(frame_b["scenario_digest"]))
    a = frame_a[shared].reset_index(drop=True)
    b = frame_b.set_index("scenario_digest").loc[a["scenario_digest"]].reset_index()
    return a, b
