"""Is a difference between two runs larger than the noise? Paired bootstrap over images / ROIs.

Each evaluation unit (an image for the full-image suite, a ROI for the ROI suite) is scored by
both runs, so the comparison is paired: the statistic is the mean over units of
``metric(run) - metric(reference)``, and its confidence interval comes from resampling the
units with replacement (Efron's percentile bootstrap). An interval that excludes 0 says the
sign of the difference is not an accident of which images were drawn; it says nothing about
seed-to-seed training noise, which needs several training runs.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd

from .errors import DataError


@dataclass(frozen=True)
class PairedDifference:
    """Mean of ``run - reference`` over ``n`` paired units with its bootstrap interval."""

    mean: float
    low: float
    high: float
    n: int
    excludes_zero: bool

    def as_dict(self) -> dict:
        return asdict(self)


def paired_bootstrap(
    values: np.ndarray, reference: np.ndarray, samples: int = 10_000, confidence: float = 0.95, seed: int = 0
) -> PairedDifference:
    """Percentile-bootstrap interval of ``mean(values - reference)``, resampling the pairs."""
    values, reference = np.asarray(values, np.float64), np.asarray(reference, np.float64)
    if values.shape != reference.shape or values.ndim != 1 or values.size == 0:
        raise ValueError(f"paired_bootstrap: need two equal-length 1-D arrays, got {values.shape} and {reference.shape}")
    if not 0 < confidence < 1:
        raise ValueError(f"paired_bootstrap: confidence must be in (0, 1), got {confidence}")
    diff = values - reference
    rng = np.random.default_rng(seed)
    means = np.empty(samples)
    # In chunks: samples x n indices at once would be 10,000 x 29,000 for a KITTI-sized ROI set.
    chunk = max(1, 2_000_000 // diff.size)
    for start in range(0, samples, chunk):
        stop = min(samples, start + chunk)
        means[start:stop] = diff[rng.integers(0, diff.size, (stop - start, diff.size))].mean(axis=1)
    alpha = (1 - confidence) / 2
    low, high = np.quantile(means, [alpha, 1 - alpha])
    return PairedDifference(float(diff.mean()), float(low), float(high), int(diff.size), bool(low > 0 or high < 0))


def paired_table(run: pd.DataFrame, reference: pd.DataFrame, keys: list[str], metric: str, what: str) -> tuple[np.ndarray, np.ndarray]:
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
