"""How many seeds would a verdict need? Sample size of a test on per-seed means, paired or not.

The unit is one training run (a seed). Its value is the run's mean metric over the images (full
frame) or over the ROIs of one class. Both losses train with the same seeds, and a seed fixes the
initial weights and the data order, so seed ``s`` of one loss and seed ``s`` of the other are a
pair (:mod:`msdepth.training.pairing`). With ``paired=True`` the test is the paired t on the
per-seed differences, whose standard deviation ``σ_d`` is what matters (small where the two
losses' runs of a seed move together):

    n = (z_{1−α/2} + z_{1−β})² σ_d² / δ²   pairs,   df = n − 1.

Unpaired (runs of different seeds, or a reference without seeds), the two-sample test below.

Normal approximation, per group (two-sided level α, power 1 − β):

    n = 2 (z_{1−α/2} + z_{1−β})² σ² / δ²

Here δ is the difference of the two variants' means and σ the per-seed standard deviation, pooled
over the variants: σ² = (s_a² + s_b²) / 2, with the sample variances of an equal number of seeds.
The t-based size allows for σ being estimated from the runs themselves. It is the smallest n whose
power under the noncentral t (:func:`power_at`, df = 2n − 2) reaches 1 − β. This is what iterating
the formula with Student-t quantiles at df = 2n − 2 in place of z approximates (Snedecor and
Cochran), without that iteration's cycling at a few seeds. It gives the usual two-sample t-test
sizes, e.g. 17 per group at δ/σ = 1 where the normal formula gives 16. Sizes are rounded up, and
are at least 2.

With three seeds per variant, σ rests on 4 degrees of freedom. An n computed from it is a rough
guide, not a promise.
"""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np

_SIMPSON_INTERVALS = 4000  # t CDF by Simpson's rule: error far below the 4 decimals that matter here


def _t_cdf(x: float, df: float) -> float:
    """Student's t cumulative distribution at ``x`` with ``df`` > 0 degrees of freedom.

    Integrates the density from 0 to |x| by Simpson's rule; no SciPy dependency for one quantile.
    """
    if df <= 0:
        raise ValueError(f"t_cdf: df must be > 0, got {df}")
    if x == 0:
        return 0.5
    log_norm = math.lgamma((df + 1) / 2) - math.lgamma(df / 2) - 0.5 * math.log(df * math.pi)
    grid = np.linspace(0.0, abs(x), _SIMPSON_INTERVALS + 1)
    density = np.exp(log_norm - (df + 1) / 2 * np.log1p(grid**2 / df))
    area = _simpson(density, abs(x) / _SIMPSON_INTERVALS)
    return 0.5 + math.copysign(min(area, 0.5), x)


def t_quantile(p: float, df: float) -> float:
    """The ``p`` quantile (0 < p < 1) of Student's t with ``df`` degrees of freedom (by bisection)."""
    if not 0 < p < 1:
        raise ValueError(f"t_quantile: p must be in (0, 1), got {p}")
    if p < 0.5:
        return -t_quantile(1 - p, df)
    low, high = 0.0, 1.0
    while _t_cdf(high, df) < p:  # heavy tails at small df: widen until the quantile is bracketed
        high *= 2
    for _ in range(60):
        mid = (low + high) / 2
        low, high = (mid, high) if _t_cdf(mid, df) < p else (low, mid)
    return (low + high) / 2


def seeds_needed(
    delta: float,
    sd: float,
    alpha: float = 0.05,
    power: float = 0.8,
    t_based: bool = True,
    paired: bool = False,
) -> float:
    """Seeds per variant (``paired``: seed pairs) for a two-sided test at level ``alpha`` to detect
    ``delta`` with probability ``power``, given the per-seed standard deviation ``sd`` (``paired``:
    of the per-seed differences; module docstring).

    Args:
        delta: the true difference to detect.
        sd: the per-seed standard deviation (paired: of the differences).
        alpha: the test's two-sided level.
        power: the probability of detecting ``delta``.
        t_based: the t-test's size; False: the normal approximation alone.
        paired: seed pairs and the paired t.

    Returns:
        The size, at least 2; ``math.inf`` when ``delta`` is 0.

    Raises:
        ValueError: a negative ``sd`` or ``alpha``, ``power`` outside (0, 1).

    Example:
        >>> seeds_needed(1.0, 1.0), seeds_needed(1.0, 1.0, paired=True)
        (17, 10)
    """
    if sd < 0 or not 0 < alpha < 1 or not 0 < power < 1:
        raise ValueError(
            f"seeds_needed: need sd >= 0, 0 < alpha < 1, 0 < power < 1; got {sd}, {alpha}, {power}"
        )
    if delta == 0:
        return math.inf
    z = NormalDist()
    normal = (1 if paired else 2) * (z.inv_cdf(1 - alpha / 2) + z.inv_cdf(power)) ** 2 * (sd / delta) ** 2
    n = max(2, math.ceil(normal))
    if not t_based:
        return n
    # The t-test is never more powerful than the z-test, so the answer is not below the normal
    # n (less one for the rounding); the t-quantile iteration can cycle at df < 10, this cannot.
    n = max(2, n - 1)
    while power_at(n, delta, sd, alpha, paired) < power:
        n += 1
    return n


def detectable_difference(
    n: int, sd: float, alpha: float = 0.05, power: float = 0.8, paired: bool = False
) -> float:
    """The smallest |δ| a two-sided t-test with ``n`` seeds per variant (``paired``: ``n`` seed
    pairs) detects with probability ``power`` at level ``alpha``, given ``sd`` (by bisection on
    :func:`power_at`).

    Args:
        n: seeds per variant, or seed pairs.
        sd: the per-seed standard deviation (paired: of the differences).
        alpha: the test's two-sided level.
        power: the probability of detecting it.
        paired: the paired t.

    Returns:
        The smallest detectable difference (0 where ``sd`` is 0).

    Example:
        >>> round(detectable_difference(12, 1.0, paired=True), 2)
        0.89
    """
    if sd == 0:
        return 0.0
    low, high = 0.0, sd
    while power_at(n, high, sd, alpha, paired) < power:
        high *= 2
    for _ in range(50):
        mid = (low + high) / 2
        low, high = (mid, high) if power_at(n, mid, sd, alpha, paired) < power else (low, mid)
    return high


def _simpson(values: np.ndarray, step: float) -> float:
    """Simpson's rule over an odd number of equally spaced samples."""
    return float(step / 3 * (values[0] + values[-1] + 4 * values[1:-1:2].sum() + 2 * values[2:-1:2].sum()))


def power_at(n: int, delta: float, sd: float, alpha: float = 0.05, paired: bool = False) -> float:
    """Power of the two-sided two-sample t-test with ``n`` seeds per variant at a true difference
    ``delta`` and per-seed standard deviation ``sd``: P(|T'| > t_{1−α/2}) for the noncentral
    T' = (Z + λ) / sqrt(V / df), λ = |δ| / (σ √(2/n)), V ~ χ²(df), df = 2n − 2, by averaging the
    normal tails over V's density (no SciPy). ``paired``: the paired t on ``n`` seed pairs, ``sd``
    that of the differences: λ = |δ| / (σ_d / √n), df = n − 1."""
    if n < 2:
        raise ValueError(f"power_at: need n >= 2 seeds per variant, got {n}")
    if sd == 0:
        return 1.0 if delta else alpha
    df = n - 1 if paired else 2 * n - 2
    shift = abs(delta) / (sd / math.sqrt(n) if paired else sd * math.sqrt(2 / n))
    crit = t_quantile(1 - alpha / 2, df)
    # Over u = sqrt(V): χ²(1)'s density is infinite at V = 0 (the paired test's df = 1), while
    # f(u²)·2u, the density of u, is smooth for every df.
    top = math.sqrt(df + 40 * math.sqrt(2 * df) + 40)  # far beyond χ²(df)'s mass
    u = np.linspace(0.0, top, 2 * _SIMPSON_INTERVALS + 1)
    log_u = np.log(np.maximum(u, np.finfo(float).tiny))
    log_density = (df - 1) * log_u - u * u / 2 - (df / 2 - 1) * math.log(2) - math.lgamma(df / 2)
    density = np.exp(log_density)
    erf = np.vectorize(math.erf)
    edge = crit * u / math.sqrt(df)
    tails = 0.5 * (1 - erf((edge - shift) / math.sqrt(2))) + 0.5 * (1 + erf((-edge - shift) / math.sqrt(2)))
    return _simpson(density * tails, top / (2 * _SIMPSON_INTERVALS))


def pooled_sd(a: list[float], b: list[float]) -> float:
    """Per-seed standard deviation pooled over two variants: sqrt((s_a² + s_b²) / 2) with equal
    seed counts, the degrees-of-freedom-weighted pool in general."""
    if len(a) < 2 or len(b) < 2:
        raise ValueError(f"pooled_sd: need at least 2 seeds per variant, got {len(a)} and {len(b)}")
    ss = float(np.var(a, ddof=1)) * (len(a) - 1) + float(np.var(b, ddof=1)) * (len(b) - 1)
    return math.sqrt(ss / (len(a) + len(b) - 2))
