"""Paired bootstrap intervals: known answers, a straightforward reimplementation, coverage, pairing."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from msdepth.compare import build_comparison, paired_statistics
from msdepth.config import CompareConfig
from msdepth.errors import DataError
from msdepth.metrics import METRICS
from msdepth.stats import paired_bootstrap, paired_table


def test_constant_difference_has_a_zero_width_interval() -> None:
    ref = np.linspace(0.1, 0.5, 17)
    d = paired_bootstrap(ref - 0.03, ref, samples=500)
    assert d.mean == pytest.approx(-0.03) and d.low == pytest.approx(-0.03) and d.high == pytest.approx(-0.03)
    assert d.excludes_zero and d.n == 17
    same = paired_bootstrap(ref, ref, samples=500)
    assert (same.mean, same.low, same.high, same.excludes_zero) == (0.0, 0.0, 0.0, False)


def test_matches_a_straightforward_loop() -> None:
    rng = np.random.default_rng(3)
    a, b = rng.normal(0.3, 0.1, 25), rng.normal(0.28, 0.1, 25)
    ours = paired_bootstrap(a, b, samples=2000, confidence=0.9, seed=7)
    draw = np.random.default_rng(7)
    means = [np.mean((a - b)[draw.integers(0, 25, 25)]) for _ in range(2000)]
    assert ours.low == pytest.approx(np.quantile(means, 0.05), abs=1e-12)
    assert ours.high == pytest.approx(np.quantile(means, 0.95), abs=1e-12)
    assert ours.mean == pytest.approx(np.mean(a - b))


def test_interval_covers_the_true_mean_about_as_often_as_claimed() -> None:
    rng = np.random.default_rng(0)
    hits = 0
    trials = 300
    for t in range(trials):
        diff = rng.normal(0.05, 0.2, 40)
        d = paired_bootstrap(diff, np.zeros(40), samples=1000, seed=t)
        hits += d.low <= 0.05 <= d.high
    assert 0.88 <= hits / trials <= 0.99  # nominal 0.95; the percentile bootstrap is a bit narrow at n = 40


def test_deterministic_for_a_seed() -> None:
    a, b = np.arange(10.0), np.arange(10.0)[::-1]
    assert paired_bootstrap(a, b, seed=1) == paired_bootstrap(a, b, seed=1)


def test_bad_inputs() -> None:
    with pytest.raises(ValueError, match="equal-length"):
        paired_bootstrap(np.ones(3), np.ones(4))
    with pytest.raises(ValueError, match="confidence"):
        paired_bootstrap(np.ones(3), np.ones(3), confidence=1.0)


def _table(frames: list[str], abs_rel: list[float], cap: float = 80) -> pd.DataFrame:
    rows = [{"frame": f, "cap": cap, **{m: v for m in METRICS}} for f, v in zip(frames, abs_rel)]
    return pd.DataFrame(rows)


def test_units_are_paired_by_key_not_by_row_order() -> None:
    run = _table(["a", "b", "c"], [1.0, 2.0, 3.0])
    ref = _table(["c", "a", "b"], [2.5, 0.5, 1.5])  # the same frames in another order
    values, reference = paired_table(run, ref, ["frame"], "abs_rel", "test")
    assert list(values - reference) == [0.5, 0.5, 0.5]
    with pytest.raises(DataError, match="different units"):
        paired_table(run, _table(["a", "b", "x"], [1, 2, 3]), ["frame"], "abs_rel", "test")
    with pytest.raises(DataError, match="duplicate"):
        paired_table(run, _table(["a", "a", "b"], [1, 2, 3]), ["frame"], "abs_rel", "test")


def test_compare_reports_intervals_and_marks_clear_differences() -> None:
    frames = [f"{i:06d}_10" for i in range(30)]
    rng = np.random.default_rng(1)
    base = rng.uniform(0.2, 0.4, 30)
    tables = {
        "full": {"ssim": _table(frames, base), "msssim": _table(frames, base - 0.05),
                 "noise": _table(frames, base + rng.normal(0, 0.01, 30))},
        "roi": {r: t.rename(columns={"frame": "roi"}) for r, t in
                {"ssim": _table(frames, base), "msssim": _table(frames, base - 0.05),
                 "noise": _table(frames, base + rng.normal(0, 0.01, 30))}.items()},
    }
    stats = paired_statistics(tables, ["ssim", "msssim", "noise"], CompareConfig(bootstrap_samples=1000), [80.0])
    assert stats["full"]["cap80"]["msssim"]["abs_rel"]["excludes_zero"]
    assert stats["full"]["cap80"]["msssim"]["abs_rel"]["mean"] == pytest.approx(-0.05)
    assert "ssim" not in stats["full"]["cap80"]
    block = {m: 0.3 for m in METRICS}
    suites = {
        "full": {r: {"cap80": block} for r in ("ssim", "msssim", "noise")},
        "roi": {r: {"cap80": {"overall": {**block, "count": 30}, "by_class": {}}} for r in ("ssim", "msssim", "noise")},
        "gradients": {r: {"cap80": {"overall": {f"pred_{g}": 1.0 for g in ("sobel_x", "sobel_y", "laplacian")},
                                    "dense_gt": {"overall": {}}}} for r in ("ssim", "msssim", "noise")},
    }
    result, md = build_comparison(suites, ["ssim", "msssim"], ["noise"], stats)
    assert result["statistics"] is stats
    assert "Difference to ssim (30 paired images)" in md and "Difference to ssim (30 paired ROIs)" in md
    assert "| msssim | -0.0500 [-0.0500, -0.0500] * |" in md
