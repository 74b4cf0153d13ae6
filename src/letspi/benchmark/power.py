"""How many windows a paired comparison needs: the exact power of the two-sided exact McNemar test. A alone fails
with probability ``p_only_a``, B with ``p_only_b``; the discordant count is Binomial(n, p_only_a + p_only_b), A's
share of it Binomial(d, p_only_a / (p_only_a + p_only_b)), the rejection region the tails of Binomial(d, 1/2) of mass
<= alpha / 2. A 1-point difference at discordance psi: p_only_a = (psi + 0.01) / 2."""

from __future__ import annotations

import numpy as np
from scipy.stats import binom


def mcnemar_power(n: int, p_only_a: float, p_only_b: float, alpha: float = 0.05) -> float:
    """Probability that the two-sided exact McNemar test at ``alpha`` rejects on ``n`` paired windows."""
    if n < 0 or p_only_a < 0 or p_only_b < 0 or p_only_a + p_only_b > 1:
        raise ValueError(f"need n >= 0 and probabilities with a sum <= 1, got {n}, {p_only_a}, {p_only_b}")
    psi = p_only_a + p_only_b
    if n == 0 or psi == 0:
        return 0.0
    d = np.arange(n + 1)
    # largest count c with P(X <= c | d, 1/2) <= alpha / 2 (-1 when none)
    c = binom.ppf(alpha / 2, d, 0.5)
    c = np.where(binom.cdf(c, d, 0.5) <= alpha / 2, c, c - 1)
    q = p_only_a / psi
    reject = np.where(c >= 0, binom.cdf(c, d, q) + binom.sf(d - c - 1, d, q), 0.0)
    return float(np.sum(binom.pmf(d, n, psi) * reject))


def alternative(discordance: float, difference: float = 0.01) -> tuple[float, float]:
    """(p_only_a, p_only_b) of a rate ``difference`` at ``discordance`` (>= the difference: B never fails alone)."""
    psi = max(discordance, difference)
    return (psi + difference) / 2, (psi - difference) / 2


def windows_needed(discordance: float, difference: float = 0.01, power: float = 0.8, alpha: float = 0.05,
                   step: int = 50, n_max: int = 200_000) -> int | None:
    """Smallest multiple of ``step`` windows at which the test reaches ``power`` (None beyond ``n_max``)."""
    p_a, p_b = alternative(discordance, difference)
    hi = step
    while mcnemar_power(hi, p_a, p_b, alpha) < power:
        hi *= 2
        if hi > n_max:
            return None
    lo = hi // 2
    while hi - lo > step:  # bisection on the step grid
        mid = (lo + hi) // 2 // step * step
        if mid <= lo:
            break
        if mcnemar_power(mid, p_a, p_b, alpha) >= power:
            hi = mid
        else:
            lo = mid
    return hi
