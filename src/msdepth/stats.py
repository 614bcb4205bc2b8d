"""Statistics of the comparison: bootstrap intervals over images and seeds, Student's t, seed power.

Units (images, ROIs) are scored by every run, so they are paired: the statistic is the mean over
units of ``metric(variant) - metric(reference)``, its interval Efron's percentile bootstrap. With
several seeds per variant each draw also resamples the seeds, so the interval widens with
seed-to-seed spread. Seed ``s`` of both losses shares its initial weights and data order (a
*pair*, :mod:`msdepth.training.pairing`): with ``paired=True`` the draws pick seed pairs, and
:func:`paired_t` over the per-seed differences is reported beside the bootstrap.

:func:`seeds_needed` sizes a t-test on per-seed means (paired: on their differences, σ_d):
``n = (1 or 2)(z_{1−α/2} + z_{1−β})² σ² / δ²`` from the normal approximation, then the smallest n
whose power under the noncentral t (:func:`power_at`) reaches 1 − β (17 per group at δ/σ = 1
where the normal formula gives 16). With three seeds σ rests on 4 degrees of freedom: a rough guide.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from statistics import NormalDist
from typing import Callable

import numpy as np
import pandas as pd

from msdepth.errors import DataError


@dataclass(frozen=True)
class PairedDifference:
    """Mean of ``run - reference`` over ``n`` paired units (and seeds) with its bootstrap interval."""

    mean: float
    low: float
    high: float
    n: int  # paired units
    seeds: int  # training runs of the run (1 for a deterministic baseline)
    reference_seeds: int
    excludes_zero: bool
    paired: bool = False  # seeds drawn as pairs (same seed, both variants)
    per_seed: tuple[float, ...] = ()  # paired: each seed pair's mean difference over the units
    t_low: float | None = None  # paired, >= 2 seeds: the paired t interval over per_seed
    t_high: float | None = None
    clusters: int | None = None  # the independent units drawn (e.g. frames of ROIs); None: the n units

    def as_dict(self) -> dict:
        d = asdict(self)
        d["per_seed"] = list(self.per_seed)
        return d


def paired_t(differences: np.ndarray, confidence: float = 0.95) -> tuple[float, float, float]:
    """``(mean, low, high)``: Student's t interval of the mean of paired ``differences`` (one per
    seed pair), ``len - 1`` degrees of freedom; needs at least 2.

    Args:
        differences: per pair, ``variant − reference``.
        confidence: the interval's level, in (0, 1).

    Returns:
        The mean and the interval's ends.

    Raises:
        ValueError: fewer than 2 differences.

    Example:
        >>> mean, low, high = paired_t(np.array([-0.039, -0.014, -0.054]))
        >>> round(mean, 3), round(low, 3), round(high, 3)
        (-0.036, -0.086, 0.015)
    """
    d = np.asarray(differences, np.float64)
    if d.ndim != 1 or len(d) < 2:
        raise ValueError(f"paired_t: need at least 2 paired differences, got shape {d.shape}")
    mean = float(d.mean())
    half = t_quantile(0.5 + confidence / 2, len(d) - 1) * float(d.std(ddof=1)) / math.sqrt(len(d))
    return mean, mean - half, mean + half


def _checked_runs(
    values: np.ndarray, reference: np.ndarray, confidence: float
) -> tuple[np.ndarray, np.ndarray]:
    """The two (seeds, units) arrays as float64; a ValueError unless they share their units."""
    values, reference = np.asarray(values, np.float64), np.asarray(reference, np.float64)
    if (
        values.ndim != 2
        or reference.ndim != 2
        or values.shape[1] != reference.shape[1]
        or 0 in values.shape + reference.shape
    ):
        raise ValueError(
            "seed_bootstrap: need two (seeds, units) arrays over the same units, "
            f"got {values.shape} and {reference.shape}"
        )
    if not 0 < confidence < 1:
        raise ValueError(f"seed_bootstrap: confidence must be in (0, 1), got {confidence}")
    return values, reference


def _chunked(samples: int, cells: int, chunk_means: Callable[[int], np.ndarray]) -> np.ndarray:
    """``samples`` bootstrap means, drawn ``chunk_means(count)`` at a time: samples x units indices
    at once would be 10,000 x 29,000 for a KITTI-sized ROI set (``cells``: units x seeds per draw)."""
    means = np.empty(samples)
    chunk = max(1, 2_000_000 // cells)
    for start in range(0, samples, chunk):
        stop = min(samples, start + chunk)
        means[start:stop] = chunk_means(stop - start)
    return means


def _interval(means: np.ndarray, confidence: float) -> tuple[float, float]:
    """The percentile interval of bootstrap ``means`` at ``confidence``."""
    alpha = (1 - confidence) / 2
    low, high = np.quantile(means, [alpha, 1 - alpha])
    return float(low), float(high)


class _UnitDraw:
    """One bootstrap draw of the units: the units themselves, or whole clusters of them.

    With ``clusters`` (one label per unit, e.g. the frame a ROI lies in) a draw resamples the
    clusters with replacement and averages every unit of the drawn ones, so units that share a
    frame are never counted as independent (the cluster bootstrap). With one unit per cluster it
    is the plain unit draw, draw for draw (the same random stream)."""

    def __init__(self, n: int, clusters: np.ndarray | None):
        self.n = n
        if clusters is None:
            self.order, self.starts, self.counts = None, None, None
            self.k = n
            return
        labels = np.asarray(clusters)
        if labels.shape != (n,):
            raise ValueError(
                f"seed_bootstrap: need one cluster label per unit ({n}), got shape {labels.shape}"
            )
        _, codes = np.unique(labels, return_inverse=True)
        self.order = np.argsort(codes, kind="stable")
        self.counts = np.bincount(codes).astype(np.float64)
        self.starts = np.concatenate([[0], np.cumsum(self.counts[:-1])]).astype(np.intp)
        self.k = len(self.counts)

    @property
    def clusters(self) -> int | None:
        """The clusters drawn; None where the units are."""
        return None if self.order is None else self.k

    def pick(self, rng: np.random.Generator, draws: int) -> np.ndarray:
        """``draws`` resamples of the units (or clusters) with replacement, (draws, k) indices."""
        return rng.integers(0, self.k, (draws, self.k))

    def means(self, diff: np.ndarray, pick: np.ndarray) -> np.ndarray:
        """Each draw's mean of ``diff`` over the picked units: ``diff`` is (units,), shared by every
        draw, or (draws, units)."""
        draws = len(pick)
        if self.order is None:
            return np.take_along_axis(np.broadcast_to(diff, (draws, self.n)), pick, axis=1).mean(axis=1)
        sums = np.broadcast_to(np.add.reduceat(diff[..., self.order], self.starts, axis=-1), (draws, self.k))
        return np.take_along_axis(sums, pick, axis=1).sum(axis=1) / self.counts[pick].sum(axis=1)


def seed_bootstrap(
    values: np.ndarray,
    reference: np.ndarray,
    samples: int = 10_000,
    confidence: float = 0.95,
    seed: int = 0,
    paired: bool = False,
    clusters: np.ndarray | None = None,
) -> PairedDifference:
    """Percentile interval of the difference of means, resampling units and seeds.

    ``values`` is (seeds, units) for the run, ``reference`` (reference seeds, units): rows are
    training runs, columns the same units in the same order. With one row each this is the plain
    paired bootstrap over units, draw for draw (:func:`paired_bootstrap`). ``paired``: row ``i`` of
    both is seed pair ``i`` (same shape needed), drawn jointly (:func:`paired_seed_bootstrap`).

    Args:
        values: the run's metric, (seeds, units).
        reference: the reference's, (reference seeds, units), the same units in the same order.
        samples: bootstrap draws.
        confidence: the interval's level.
        seed: the draws' random seed.
        paired: draw seed pairs jointly.
        clusters: one label per unit (e.g. the frame of each ROI): draw whole clusters, the
            independent units, instead of single units (:class:`_UnitDraw`). None: units are independent.

    Returns:
        The mean difference over units (and seeds) with its percentile interval.

    Example:
        >>> d = seed_bootstrap(np.array([[1.0, 2.0, 3.0]]), np.array([[0.5, 1.5, 2.5]]), samples=200)
        >>> d.mean, d.low, d.high, d.n
        (0.5, 0.5, 0.5, 3)
    """
    if paired:
        return paired_seed_bootstrap(values, reference, samples, confidence, seed, clusters)
    values, reference = _checked_runs(values, reference, confidence)
    (sv, n), sr = values.shape, reference.shape[0]
    draw = _UnitDraw(n, clusters)
    rng = np.random.default_rng(seed)

    def runs_mean(rows: np.ndarray, count: int) -> np.ndarray:
        # One run: no draw at all, so that the stream matches the one-level bootstrap.
        return (
            rows[0] if len(rows) == 1 else rows[rng.integers(0, len(rows), (count, len(rows)))].mean(axis=1)
        )

    def chunk_means(count: int) -> np.ndarray:
        pick = draw.pick(rng, count)  # before the seeds: the stream of the one-level bootstrap
        return draw.means(runs_mean(values, count) - runs_mean(reference, count), pick)

    low, high = _interval(_chunked(samples, n * max(sv, sr), chunk_means), confidence)
    mean = float((values.mean(axis=0) - reference.mean(axis=0)).mean())
    excludes = bool(low > 0 or high < 0)
    return PairedDifference(mean, low, high, n, sv, sr, excludes, clusters=draw.clusters)


def paired_seed_bootstrap(
    values: np.ndarray,
    reference: np.ndarray,
    samples: int = 10_000,
    confidence: float = 0.95,
    seed: int = 0,
    clusters: np.ndarray | None = None,
) -> PairedDifference:
    """The bootstrap of a paired design: ``values`` and ``reference`` are (seed pairs, units), row
    ``i`` of both trained with the same seed. Each draw resamples the seed pairs and the units
    (both with replacement) and averages ``values − reference`` over the chosen cells; the
    percentile interval of those means, with :func:`paired_t` over the per-seed mean differences
    beside it (``t_low``, ``t_high``; None with one pair).

    Args:
        values: the variant's metric, (seed pairs, units).
        reference: the reference's, the same shape, row ``i`` the same seed as ``values``' row ``i``.
        samples: bootstrap draws.
        confidence: the interval's level.
        seed: the draws' random seed.
        clusters: one label per unit: draw whole clusters of units (see :func:`seed_bootstrap`).

    Returns:
        The mean difference, its percentile interval, the per-seed differences and the paired t.

    Raises:
        ValueError: arrays of other shapes, or a confidence outside (0, 1).

    Example:
        >>> v = np.array([[0.50, 0.60, 0.40], [0.52, 0.61, 0.43]])
        >>> r = v + np.array([[0.03], [0.05]])
        >>> d = paired_seed_bootstrap(v, r, samples=500)
        >>> round(d.mean, 3), d.paired, [round(x, 3) for x in d.per_seed], d.low < d.high < 0
        (-0.04, True, [-0.03, -0.05], True)
    """
    values, reference = np.asarray(values, np.float64), np.asarray(reference, np.float64)
    if values.ndim != 2 or values.shape != reference.shape or 0 in values.shape:
        raise ValueError(
            f"paired_seed_bootstrap: need two (seed pairs, units) arrays of one shape, got {values.shape} "
            f"and {reference.shape}"
        )
    if not 0 < confidence < 1:
        raise ValueError(f"paired_seed_bootstrap: confidence must be in (0, 1), got {confidence}")
    diff = values - reference
    pairs, n = diff.shape
    draw = _UnitDraw(n, clusters)
    rng = np.random.default_rng(seed)

    def chunk_means(count: int) -> np.ndarray:
        # One pair: no seed draw, so that the stream matches the one-level bootstrap's.
        rows = diff[None] if pairs == 1 else diff[rng.integers(0, pairs, (count, pairs))]
        return draw.means(rows.mean(axis=1), draw.pick(rng, count))  # (draws, units) or (1, units)

    low, high = _interval(_chunked(samples, n * pairs, chunk_means), confidence)
    per_seed = tuple(float(x) for x in diff.mean(axis=1))
    _, t_low, t_high = paired_t(np.array(per_seed), confidence) if pairs >= 2 else (None, None, None)
    excludes = bool(low > 0 or high < 0)
    return PairedDifference(
        float(diff.mean()), low, high, n, pairs, pairs, excludes, True, per_seed, t_low, t_high, draw.clusters
    )


def paired_bootstrap(
    values: np.ndarray, reference: np.ndarray, samples: int = 10_000, confidence: float = 0.95, seed: int = 0
) -> PairedDifference:
    """Percentile-bootstrap interval of ``mean(values - reference)``, resampling the pairs (one run
    each); :func:`seed_bootstrap` of one row each, which also draws clusters of pairs."""
    values, reference = np.asarray(values, np.float64), np.asarray(reference, np.float64)
    if values.shape != reference.shape or values.ndim != 1 or values.size == 0:
        raise ValueError(
            f"paired_bootstrap: need two equal-length 1-D arrays, got {values.shape} and {reference.shape}"
        )
    return seed_bootstrap(values[None], reference[None], samples, confidence, seed)


def paired_table(
    run: pd.DataFrame, reference: pd.DataFrame, keys: list[str], metric: str, what: str
) -> tuple[np.ndarray, np.ndarray]:
    """The ``metric`` column of two per-unit tables, aligned on ``keys`` (which must match one to one)."""
    a = run.set_index(keys)[metric]
    b = reference.set_index(keys)[metric]
    if a.index.has_duplicates or b.index.has_duplicates:
        raise DataError(f"{what}: duplicate rows for the same {keys}")
    if set(a.index) != set(b.index):
        only = sorted(set(a.index) ^ set(b.index))[:5]
        raise DataError(f"{what}: the two runs were evaluated on different units, e.g. {only}")
    b = b.loc[a.index]
    return a.to_numpy(), b.to_numpy()


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
