"""Is a difference between two loss variants larger than the noise? Bootstrap over images and seeds.

Each evaluation unit (an image for the full-image suite, a ROI for the ROI suite) is scored by
every run, so units are paired: the statistic is the mean over units of ``metric(variant) -
metric(reference)``. With one training run per variant its interval comes from resampling the
units with replacement (Efron's percentile bootstrap); it covers the choice of images, not
training noise. With several seeds per variant the bootstrap is two-level: every resample draws
the units (shared by all runs, so still paired) and, independently for each variant, its seeds
with replacement, and averages the chosen runs. The interval then widens with seed-to-seed
spread, so a difference that only one lucky seed produced does not exclude 0.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

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

    def as_dict(self) -> dict:
        return asdict(self)


def seed_bootstrap(
    values: np.ndarray, reference: np.ndarray, samples: int = 10_000, confidence: float = 0.95, seed: int = 0
) -> PairedDifference:
    """Percentile interval of the difference of means, resampling units and each side's seeds.

    ``values`` is (seeds, units) for the run, ``reference`` (reference seeds, units): rows are
    training runs, columns the same units in the same order. With one row each this is the plain
    paired bootstrap over units, draw for draw (:func:`paired_bootstrap`).
    """
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
    (sv, n), sr = values.shape, reference.shape[0]
    rng = np.random.default_rng(seed)

    def runs_mean(rows: np.ndarray, count: int) -> np.ndarray:
        # One run: no draw at all, so that the stream matches the one-level bootstrap.
        return (
            rows[0] if len(rows) == 1 else rows[rng.integers(0, len(rows), (count, len(rows)))].mean(axis=1)
        )

    means = np.empty(samples)
    # In chunks: samples x n indices at once would be 10,000 x 29,000 for a KITTI-sized ROI set.
    chunk = max(1, 2_000_000 // (n * max(sv, sr)))
    for start in range(0, samples, chunk):
        stop = min(samples, start + chunk)
        units = rng.integers(0, n, (stop - start, n))
        diff = runs_mean(values, stop - start) - runs_mean(
            reference, stop - start
        )  # (units,) or (draws, units)
        picked = diff[units] if diff.ndim == 1 else np.take_along_axis(diff, units, axis=1)
        means[start:stop] = picked.mean(axis=1)
    alpha = (1 - confidence) / 2
    low, high = np.quantile(means, [alpha, 1 - alpha])
    mean = float((values.mean(axis=0) - reference.mean(axis=0)).mean())
    return PairedDifference(mean, float(low), float(high), n, sv, sr, bool(low > 0 or high < 0))


def paired_bootstrap(
    values: np.ndarray, reference: np.ndarray, samples: int = 10_000, confidence: float = 0.95, seed: int = 0
) -> PairedDifference:
    """Percentile-bootstrap interval of ``mean(values - reference)``, resampling the pairs (one run each)."""
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
