"""Uncertainty of evaluation figures: Wilson intervals, exact McNemar tests, vehicle (cluster) bootstrap.

Windows of one ego vehicle overlap, so they are not independent: rates get Wilson intervals at the effective
sample size n / ``design_effect`` (Korn & Graubard 1998), means a percentile bootstrap over whole groups
(``letspi.scenario.split.vehicle_keys``). Resamples come from ``numpy.random.default_rng(seed)`` over the sorted
groups and interval ends are rounded to ``SIGNIFICANT_DIGITS``: byte-identical across runs and BLAS builds.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from statistics import NormalDist
from typing import Any, Final

import numpy as np

LEVEL: Final = 0.95
N_RESAMPLES: Final = 2000
SEED: Final = 0
#: interval ends are rounded to this many significant digits (module doc)
SIGNIFICANT_DIGITS: Final = 6
#: a paired mean difference (or interval end) within this fraction of the values' magnitude is 0 (float noise)
FLOAT_NOISE_REL: Final = 1e-9

Interval = tuple[float, float]
NAN_INTERVAL: Final[Interval] = (math.nan, math.nan)


def rounded(x: float, digits: int = SIGNIFICANT_DIGITS) -> float:
    """``x`` rounded to ``digits`` significant digits (NaN and inf unchanged)."""
    if not math.isfinite(x) or x == 0.0:
        return float(x)
    return float(f"{x:.{digits}g}")


def _check_level(level: float) -> None:
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")


def wilson_interval(k: int, n: int, level: float = LEVEL) -> Interval:
    """Wilson score interval (no continuity correction) of ``k`` successes in ``n`` trials, in [0, 1]; NaN if n = 0."""
    _check_level(level)
    k, n = int(k), int(n)
    if n < 0 or not 0 <= k <= max(n, 0):
        raise ValueError(f"need 0 <= k <= n, got k={k}, n={n}")
    if n == 0:
        return NAN_INTERVAL
    return wilson_ends(k / n, n, level)


def wilson_ends(p_hat: float, n: float, level: float = LEVEL) -> Interval:
    """Wilson score interval of a proportion ``p_hat`` in ``n`` (possibly effective, non-integer) trials."""
    _check_level(level)
    if n <= 0:
        return NAN_INTERVAL
    z = NormalDist().inv_cdf(0.5 + level / 2)
    shrink = 1.0 + z * z / n
    centre = (p_hat + z * z / (2 * n)) / shrink
    half = z / shrink * math.sqrt(max(p_hat * (1.0 - p_hat), 0.0) / n + z * z / (4 * n * n))
    low = 0.0 if p_hat <= 0.0 else max(0.0, centre - half)  # exactly 0 / 1 at the ends, not 1e-17 off
    high = 1.0 if p_hat >= 1.0 else min(1.0, centre + half)
    return rounded(low), rounded(high)


def design_effect(flags: np.ndarray | Sequence[bool], groups: np.ndarray | Sequence[Any]) -> float:
    """How much grouping windows by vehicle inflates the variance of their share, >= 1 (Korn & Graubard 1998):
    G / (G - 1) · Σ_g (y_g - p m_g)² / n² over p (1 - p) / n; 1 when not estimable (p 0 or 1, < 2 groups)."""
    y = np.asarray(flags, dtype=np.float64)
    inverse, n_groups = group_index(groups)
    if len(inverse) != len(y):
        raise ValueError(f"flags has {len(y)} rows, groups {len(inverse)}")
    n = len(y)
    p = float(y.mean()) if n else 0.0
    if n_groups < 2 or n_groups == n or p <= 0.0 or p >= 1.0:  # one window per group: independent trials
        return 1.0
    events = np.bincount(inverse, weights=y, minlength=n_groups)
    sizes = np.bincount(inverse, minlength=n_groups).astype(np.float64)
    clustered = n_groups / (n_groups - 1) * float(np.sum((events - p * sizes) ** 2)) / (n * n)
    return max(1.0, clustered / (p * (1.0 - p) / n))


def vehicle_wilson_interval(flags: np.ndarray | Sequence[bool], groups: np.ndarray | Sequence[Any],
                            level: float = LEVEL) -> Interval:
    """Wilson interval of the share of ``flags`` (n,) at the effective sample size n / ``design_effect`` of their
    ``groups`` (n,); ``wilson_interval`` with one window per vehicle, (NaN, NaN) when n is 0."""
    y = np.asarray(flags, dtype=bool)
    if not len(y):
        return NAN_INTERVAL
    return wilson_ends(float(y.mean()), len(y) / design_effect(y, groups), level)


def mcnemar_exact(n_only_a: int, n_only_b: int) -> float:
    """Two-sided exact McNemar p: the binomial test of ``n_only_a`` of ``n_only_a + n_only_b`` against 1/2."""
    b, c = int(n_only_a), int(n_only_b)
    if b < 0 or c < 0:
        raise ValueError(f"discordant counts must be >= 0, got {b}, {c}")
    if b == c:  # includes no discordant pairs
        return 1.0
    return min(1.0, 2.0 * binomial_half_cdf(min(b, c), b + c))


def binomial_half_cdf(m: int, n: int) -> float:
    """P(X <= m) for X ~ Binomial(n, 1/2), summed in integers and divided by 2^n once (correctly rounded)."""
    term = total = 1
    for i in range(m):
        term = term * (n - i) // (i + 1)
        total += term
    return total / 2**n


def group_index(groups: np.ndarray | Sequence[Any]) -> tuple[np.ndarray, int]:
    """(n,) int index of each row's group in the sorted unique groups, and their number G."""
    keys = np.asarray(groups).astype(str)
    uniq, inverse = np.unique(keys, return_inverse=True)
    return inverse.reshape(-1), len(uniq)


#: resamples drawn per chunk (bounds memory at about 16 * RESAMPLE_CHUNK * G bytes; part of the seeded stream)
RESAMPLE_CHUNK: Final = 250


def resample_counts(n_groups: int, n_resamples: int = N_RESAMPLES, seed: int = SEED) -> Iterator[np.ndarray]:
    """Chunks (r, G) float64: per resample, how often each of G groups is drawn in G draws with replacement;
    ``n_resamples`` rows in all, from one seeded stream."""
    if n_resamples < 1:
        raise ValueError(f"n_resamples must be >= 1, got {n_resamples}")
    rng = np.random.default_rng(seed)
    for start in range(0, n_resamples, RESAMPLE_CHUNK):
        r = min(RESAMPLE_CHUNK, n_resamples - start)
        draws = rng.integers(0, n_groups, size=(r, n_groups))
        flat = (draws + n_groups * np.arange(r)[:, None]).ravel()
        yield np.bincount(flat, minlength=r * n_groups).reshape(r, n_groups).astype(np.float64)


def bootstrap_mean_intervals(values: np.ndarray, groups: np.ndarray | Sequence[Any], level: float = LEVEL,
                             n_resamples: int = N_RESAMPLES, seed: int = SEED) -> np.ndarray:
    """Vehicle-bootstrap percentile intervals (K, 2) of the finite means of ``values`` (n, K) or (n,) (shared
    resamples; ``groups`` (n,) compared as strings); NaN for a column with < 2 groups holding a finite value."""
    _check_level(level)
    v = np.asarray(values, dtype=np.float64)
    v2 = v.reshape(len(v), -1)
    inverse, n_groups = group_index(groups)
    if len(inverse) != len(v2):
        raise ValueError(f"values has {len(v2)} rows, groups {len(inverse)}")
    out = np.full((v2.shape[1], 2), np.nan)
    if not len(v2):
        return out
    finite = np.isfinite(v2)
    sums = np.zeros((n_groups, v2.shape[1]))
    counts = np.zeros((n_groups, v2.shape[1]))
    np.add.at(sums, inverse, np.where(finite, v2, 0.0))
    np.add.at(counts, inverse, finite.astype(np.float64))
    with np.errstate(invalid="ignore", divide="ignore"):  # NaN where a resample has no finite value
        means = np.concatenate([(w @ sums) / (w @ counts) for w in resample_counts(n_groups, n_resamples, seed)])
    alpha = 1.0 - level
    estimable = (counts > 0).sum(axis=0) >= 2
    if estimable.any():
        q = np.nanquantile(means[:, estimable], [alpha / 2, 1 - alpha / 2], axis=0)  # (2, K')
        out[estimable] = q.T
    return np.vectorize(rounded, otypes=[np.float64])(out) if out.size else out


def bootstrap_mean_interval(values: np.ndarray | Sequence[float], groups: np.ndarray | Sequence[Any],
                            level: float = LEVEL, n_resamples: int = N_RESAMPLES, seed: int = SEED) -> Interval:
    """``bootstrap_mean_intervals`` of one column ``values`` (n,)."""
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 1:
        raise ValueError(f"values must be 1-D, got shape {v.shape}")
    low, high = bootstrap_mean_intervals(v[:, None], groups, level, n_resamples, seed)[0]
    return float(low), float(high)


def _json_float(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


@dataclass(frozen=True)
class PairedRate:
    """Paired comparison of a rate of A and B on the same windows: ``n_only_a`` windows where only A's flag is set;
    ``diff`` A minus B in percentage points, ``diff_ci95`` its vehicle-bootstrap interval."""

    n_pairs: int
    n_only_a: int
    n_only_b: int
    n_both: int
    p_mcnemar: float
    diff: float
    diff_ci95: Interval

    def record(self) -> dict[str, Any]:
        """The ``metrics.json`` entry, A being the planner and B the reference (NaN -> None)."""
        return {"n_pairs": self.n_pairs, "n_only_planner": self.n_only_a, "n_only_reference": self.n_only_b,
                "n_both": self.n_both, "p_mcnemar": rounded(self.p_mcnemar), "diff": _json_float(self.diff),
                "diff_ci95": [_json_float(self.diff_ci95[0]), _json_float(self.diff_ci95[1])]}


@dataclass(frozen=True)
class PairedMean:
    """Paired comparison of a mean of A and B: over the windows where both are finite, the mean of A - B and its
    vehicle-bootstrap interval."""

    n_pairs: int
    diff: float
    diff_ci95: Interval

    def record(self) -> dict[str, Any]:
        """The ``metrics.json`` entry (NaN -> None)."""
        return {"n_pairs": self.n_pairs, "diff": _json_float(self.diff),
                "diff_ci95": [_json_float(self.diff_ci95[0]), _json_float(self.diff_ci95[1])]}


def _same_length(*arrays: np.ndarray) -> None:
    if len({len(a) for a in arrays}) != 1:
        raise ValueError(f"paired inputs differ in length: {[len(a) for a in arrays]}")


def _rate_columns(fail_a: np.ndarray | Sequence[bool], fail_b: np.ndarray | Sequence[bool]
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    a = np.asarray(fail_a, dtype=bool)
    b = np.asarray(fail_b, dtype=bool)
    _same_length(a, b)
    return a, b, 100.0 * (a.astype(np.float64) - b.astype(np.float64))


def _mean_columns(a: np.ndarray | Sequence[float], b: np.ndarray | Sequence[float]
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    va = np.asarray(a, dtype=np.float64)
    vb = np.asarray(b, dtype=np.float64)
    _same_length(va, vb)
    ok = np.isfinite(va) & np.isfinite(vb)
    with np.errstate(invalid="ignore"):  # inf - inf: left out anyway
        return va, vb, np.where(ok, va - vb, np.nan)


def paired_comparisons(pairs: Sequence[tuple[str, np.ndarray | Sequence[Any], np.ndarray | Sequence[Any]]],
                       groups: np.ndarray | Sequence[Any], level: float = LEVEL, n_resamples: int = N_RESAMPLES,
                       seed: int = SEED) -> list[PairedRate | PairedMean]:
    """``paired_rate`` / ``paired_mean`` of many ("rate" or "mean", A (n,), B (n,)) pairs of the same windows at
    once, sharing one set of vehicle resamples."""
    g = np.asarray(groups)
    columns = [(kind, *(_rate_columns(a, b) if kind == "rate" else _mean_columns(a, b))) for kind, a, b in pairs]
    for _, a, _, _ in columns:
        _same_length(a, g)
    if not columns:
        return []
    diffs = np.stack([d for *_, d in columns], axis=1)
    ends = (bootstrap_mean_intervals(diffs, g, level, n_resamples, seed) if len(g)
            else np.full((len(columns), 2), np.nan))
    out: list[PairedRate | PairedMean] = []
    for (kind, a, b, d), (low, high) in zip(columns, ends, strict=True):
        ok = np.isfinite(d)
        n = int(ok.sum())
        diff = float(d[ok].mean()) if n else math.nan
        ci = (float(low), float(high))
        if kind == "rate":
            only_a, only_b = int((a & ~b).sum()), int((b & ~a).sum())
            out.append(PairedRate(n_pairs=len(a), n_only_a=only_a, n_only_b=only_b, n_both=int((a & b).sum()),
                                  p_mcnemar=mcnemar_exact(only_a, only_b), diff=diff, diff_ci95=ci))
            continue
        if n:  # float noise of two computations of the same value (e.g. 1e-13 m) is no difference
            noise = FLOAT_NOISE_REL * float(max(np.abs(a[ok]).max(), np.abs(b[ok]).max()))
            diff = 0.0 if abs(diff) <= noise else diff
            ci = (0.0 if abs(ci[0]) <= noise else ci[0], 0.0 if abs(ci[1]) <= noise else ci[1])
        out.append(PairedMean(n_pairs=n, diff=diff, diff_ci95=ci))
    return out


def paired_rate(fail_a: np.ndarray | Sequence[bool], fail_b: np.ndarray | Sequence[bool],
                groups: np.ndarray | Sequence[Any], level: float = LEVEL, n_resamples: int = N_RESAMPLES,
                seed: int = SEED) -> PairedRate:
    """Paired comparison of two (n,) boolean outcomes of the same windows (``groups`` (n,): their vehicles):
    discordant counts, exact McNemar p, A - B in percentage points with its vehicle-bootstrap interval."""
    result = paired_comparisons([("rate", fail_a, fail_b)], groups, level, n_resamples, seed)[0]
    assert isinstance(result, PairedRate)
    return result


def paired_mean(a: np.ndarray | Sequence[float], b: np.ndarray | Sequence[float], groups: np.ndarray | Sequence[Any],
                level: float = LEVEL, n_resamples: int = N_RESAMPLES, seed: int = SEED) -> PairedMean:
    """Paired comparison of two (n,) per-window values: mean of A - B over the pairs where both are finite (the
    others' vehicles are still resampled), and its vehicle-bootstrap interval."""
    result = paired_comparisons([("mean", a, b)], groups, level, n_resamples, seed)[0]
    assert isinstance(result, PairedMean)
    return result
