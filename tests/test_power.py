"""Seeds a verdict needs (msdepth.stats): hand-computed sizes, and t quantiles and
powers against SciPy's values (scipy.stats.t.ppf, scipy.stats.nct, written down here: SciPy is
not a dependency)."""

from __future__ import annotations

import math

import pytest

from msdepth.stats import _t_cdf, pooled_sd, power_at, seeds_needed, t_quantile


def test_normal_size_by_hand() -> None:
    # z_0.975 = 1.959964, z_0.8 = 0.841621: 2 (2.801585)² = 15.698 per group at δ = σ -> 16;
    # at δ = σ/2 four times that, 62.79 -> 63.
    assert seeds_needed(1.0, 1.0, t_based=False) == 16
    assert seeds_needed(0.5, 1.0, t_based=False) == 63
    assert seeds_needed(-0.02, 0.02, t_based=False) == 16  # only |δ| / σ matters


def test_t_size_is_the_two_sample_t_tests() -> None:
    # The textbook sizes of the two-sided two-sample t-test at 80 % power (G*Power, SciPy's nct).
    assert seeds_needed(1.0, 1.0) == 17
    assert seeds_needed(0.5, 1.0) == 64
    assert seeds_needed(2.0, 1.0) == 6
    assert seeds_needed(3.2, 1.0) == 3  # where the plain t-quantile iteration cycles (2 <-> 6)


def test_edge_cases() -> None:
    assert seeds_needed(0.0, 1.0) == math.inf
    assert seeds_needed(0.1, 0.0) == 2  # no spread: the smallest design
    with pytest.raises(ValueError, match="alpha"):
        seeds_needed(1.0, 1.0, alpha=1.5)
    with pytest.raises(ValueError, match="n >= 2"):
        power_at(1, 1.0, 1.0)


@pytest.mark.parametrize(
    ("p", "df", "expected"),
    [
        (0.975, 4, 2.776445),
        (0.975, 30, 2.042272),
        (0.8, 30, 0.853767),
        (0.975, 2, 4.302653),
        (0.999, 3, 10.214532),
    ],
)
def test_t_quantile_matches_scipy(p: float, df: int, expected: float) -> None:
    assert t_quantile(p, df) == pytest.approx(expected, abs=1e-6)
    assert t_quantile(1 - p, df) == pytest.approx(-expected, abs=1e-6)
    assert _t_cdf(expected, df) == pytest.approx(p, abs=1e-6)  # expected is rounded to 1e-6


@pytest.mark.parametrize(
    ("n", "effect", "expected"), [(3, 1.0, 0.15879), (3, 3.0, 0.78255), (12, 0.8, 0.46576), (2, 2.0, 0.21831)]
)
def test_power_matches_scipys_noncentral_t(n: int, effect: float, expected: float) -> None:
    assert power_at(n, effect, 1.0) == pytest.approx(expected, abs=5e-5)


def test_pooled_sd_by_hand() -> None:
    # variances 1 and 4 over 3 seeds each: sqrt((2·1 + 2·4) / 4) = sqrt(2.5)
    assert pooled_sd([1.0, 2.0, 3.0], [2.0, 4.0, 6.0]) == pytest.approx(math.sqrt(2.5))
    with pytest.raises(ValueError, match="at least 2"):
        pooled_sd([1.0], [1.0, 2.0])


def test_paired_power_matches_a_simulation_down_to_one_degree_of_freedom() -> None:
    """The paired t on n seed pairs (df = n - 1, χ²(1)'s infinite density at 0 included): the
    power a 200,000-draw simulation of the test measured (seed 0: 0.154, 0.397, 0.403)."""
    from msdepth.stats import detectable_difference

    assert power_at(2, 1.76, 1.0, paired=True) == pytest.approx(0.154, abs=0.004)
    assert power_at(3, 1.76, 1.0, paired=True) == pytest.approx(0.397, abs=0.004)
    assert power_at(5, 1.0, 1.0, paired=True) == pytest.approx(0.403, abs=0.004)
    # The size is the first n whose power reaches 80 %, and the detectable δ is where it does.
    n = seeds_needed(1.76, 1.0, paired=True)
    assert power_at(n, 1.76, 1.0, paired=True) >= 0.8 > power_at(n - 1, 1.76, 1.0, paired=True)
    assert power_at(3, detectable_difference(3, 1.0, paired=True), 1.0, paired=True) == pytest.approx(
        0.8, abs=1e-3
    )


def test_the_power_study_reads_a_compare_json_and_pairs_its_seeds(tmp_path, capsys, monkeypatch) -> None:
    """studies/power.py --compare: δ is the mean of the per-seed differences and σ_d their sd, and
    seeds that move together (r = 1) need few pairs where the unpaired test would need many."""
    import json
    import sys
    from pathlib import Path

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "studies"))
    from power import main

    ssim = [0.50, 0.60, 0.55, 0.45]
    msssim = [0.47, 0.58, 0.51, 0.43]  # differences -0.03, -0.02, -0.04, -0.02

    def spread(values: list[float], name: str) -> dict:
        return {"abs_rel": {"runs": {f"{name}/seed{i}": v for i, v in enumerate(values)}}}

    data = {
        "variants": ["ssim", "msssim"],
        "seeds": [0, 1, 2, 3],
        "statistics": {"reference": "ssim"},
        "seed_spread": {
            s: {"cap80": {"ssim": spread(ssim, "ssim"), "msssim": spread(msssim, "msssim")}}
            for s in ("full", "roi")
        },
    }
    path = tmp_path / "compare.json"
    path.write_text(json.dumps(data))
    assert main(["--compare", str(path)]) == 0
    row = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("| full frame |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    # δ with its paired t interval (excluding 0: all four differences negative), and σ_d
    assert cells[3].startswith("\u22120.0275 [") and cells[3].endswith("] *") and cells[4] == "0.0096"
    assert int(cells[6]) < int(cells[11])  # pairs needed < unpaired seeds needed
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"variants": []}))
    assert main(["--compare", str(bad)]) == 1
    assert "not the per-seed values" in capsys.readouterr().err
    del sys.modules["power"]
