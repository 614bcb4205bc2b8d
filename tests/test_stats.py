"""Paired bootstrap intervals: known answers, a straightforward reimplementation, coverage, pairing."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest

from msdepth.analysis.comparison import comparison_data
from msdepth.analysis.runs import _mean_over_runs, image_dependence, paired_statistics, seed_spread
from msdepth.config.params import CompareConfig
from msdepth.errors import DataError
from msdepth.evaluation.metrics import METRICS
from msdepth.reporting.comparison import build_comparison
from msdepth.stats import paired_bootstrap, paired_table, seed_bootstrap


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
    rows = [{"frame": f, "cap": cap, **{m: v for m in METRICS}} for f, v in zip(frames, abs_rel, strict=True)]
    return pd.DataFrame(rows)


def _as_rois(table: pd.DataFrame) -> pd.DataFrame:
    """A full-image table as a ROI table: each frame one ROI in a frame of its own."""
    return table.rename(columns={"frame": "roi"}).assign(image=table["frame"].to_numpy())


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
        "full": {
            "ssim": _table(frames, base),
            "msssim": _table(frames, base - 0.05),
            "noise": _table(frames, base + rng.normal(0, 0.01, 30)),
        },
        "roi": {
            r: t.pipe(_as_rois)
            for r, t in {
                "ssim": _table(frames, base),
                "msssim": _table(frames, base - 0.05),
                "noise": _table(frames, base + rng.normal(0, 0.01, 30)),
            }.items()
        },
    }
    groups = {r: [r] for r in ("ssim", "msssim", "noise")}
    stats = paired_statistics(tables, groups, CompareConfig(bootstrap_samples=1000), [80.0])
    assert stats["full"]["cap80"]["msssim"]["abs_rel"]["excludes_zero"]
    assert stats["full"]["cap80"]["msssim"]["abs_rel"]["mean"] == pytest.approx(-0.05)
    assert "ssim" not in stats["full"]["cap80"]
    block = {m: 0.3 for m in METRICS}
    suites = {
        "full": {r: {"cap80": block} for r in ("ssim", "msssim", "noise")},
        "roi": {
            r: {"cap80": {"overall": {**block, "count": 30}, "by_class": {}}}
            for r in ("ssim", "msssim", "noise")
        },
        "gradients": {
            r: {
                "cap80": {
                    "overall": {f"pred_{g}": 1.0 for g in ("sobel_x", "sobel_y", "laplacian")},
                    "dense_gt": {"overall": {}},
                }
            }
            for r in ("ssim", "msssim", "noise")
        },
    }
    result, md = build_comparison(comparison_data(suites, ["ssim", "msssim"], ["noise"], stats=stats))
    assert result["statistics"] is stats
    assert "Difference to ssim (30 paired images)" in md
    assert "Difference to ssim (30 paired ROIs in 30 frames, drawn by frame)" in md
    # One seed: the interval covers the images only, so even a clear difference is not marked.
    assert "| msssim | -0.0500 [-0.0500, -0.0500] |" in md and " * |" not in md
    assert "so no difference is marked" in md


def test_differences_are_marked_only_over_at_least_three_seeds() -> None:
    frames = [f"{i:06d}_10" for i in range(30)]
    base = np.random.default_rng(2).uniform(0.2, 0.4, 30)
    runs = {
        f"{v}/seed{s}": _table(frames, base - (0.05 if v == "msssim" else 0.0) + 0.001 * s)
        for v in ("ssim", "msssim")
        for s in range(3)
    }
    runs["prior"] = _table(frames, base + 0.2)
    tables = {"full": runs, "roi": {r: t.pipe(_as_rois) for r, t in runs.items()}}
    block = {m: 0.3 for m in METRICS}
    grad = {
        "cap80": {
            "overall": {f"pred_{g}": 1.0 for g in ("sobel_x", "sobel_y", "laplacian")},
            "dense_gt": {"overall": {}},
        }
    }
    groups3 = {
        "ssim": [f"ssim/seed{s}" for s in range(3)],
        "msssim": [f"msssim/seed{s}" for s in range(3)],
        "prior": ["prior"],
    }
    for groups, seeds, marked in (
        (groups3, [0, 1, 2], True),
        ({k: v[:2] for k, v in groups3.items()}, [0, 1], False),
    ):
        stats = paired_statistics(tables, groups, CompareConfig(bootstrap_samples=500), [80.0])
        suites = {
            "full": {g: {"cap80": block} for g in groups},
            "roi": {g: {"cap80": {"overall": {**block, "count": 30}, "by_class": {}}} for g in groups},
            "gradients": {g: grad for g in groups},
        }
        _, md = build_comparison(
            comparison_data(suites, ["ssim", "msssim"], ["prior"], seeds=seeds, stats=stats)
        )
        assert ("| msssim | -0.0500 [" in md) and ("] * |" in md) == marked, md
        # The baseline is deterministic: its mark needs only the reference's seeds.
        assert bool(re.search(r"\| prior \| \+0\.19\d\d \[[^]]+\] \*", md)) == marked


def test_an_image_blind_run_is_flagged_in_words() -> None:
    frames = [f"{i:06d}_10" for i in range(10)]
    rng = np.random.default_rng(3)
    prior_errors = rng.uniform(0.2, 0.5, 10)
    runs = {
        "ssim/seed0": _table(frames, rng.uniform(0.1, 0.3, 10)),
        "msssim/seed0": _table(frames, prior_errors + 0.001),
        "prior": _table(frames, prior_errors),
    }
    tables = {"full": runs, "roi": {r: t.pipe(_as_rois) for r, t in runs.items()}}
    groups = {"ssim": ["ssim/seed0"], "msssim": ["msssim/seed0"], "prior": ["prior"]}
    ratios = {"ssim/seed0": 0.9, "msssim/seed0": 0.02, "prior": 0.0}
    block = {m: 0.3 for m in METRICS}
    per_run = {r: {"cap80": block, "image_dependence": {"variation_ratio": v}} for r, v in ratios.items()}
    dependence = image_dependence({"full": per_run}, tables, groups, "prior", 80.0)
    assert dependence["msssim/seed0"]["image_blind"] and not dependence["ssim/seed0"]["image_blind"]
    assert dependence["msssim/seed0"]["prior_correlation"] == pytest.approx(1.0, abs=1e-3)
    assert dependence["prior"]["prior_correlation"] is None
    suites = {
        "full": {g: {"cap80": block} for g in groups},
        "roi": {g: {"cap80": {"overall": {**block, "count": 10}, "by_class": {}}} for g in groups},
        "gradients": {
            g: {
                "cap80": {
                    "overall": {f"pred_{x}": 1.0 for x in ("sobel_x", "sobel_y", "laplacian")},
                    "dense_gt": {"overall": {}},
                }
            }
            for g in groups
        },
    }
    result, md = build_comparison(
        comparison_data(suites, ["ssim", "msssim"], ["prior"], dependence=dependence, groups=groups)
    )
    assert "| msssim (image-blind) |" in md and "| ssim |" in md
    assert (
        "| msssim/seed0 | 0.0200 | 1.0000 | image-blind: its predictions barely change between images |" in md
    )
    assert result["image_dependence"] is dependence


# --- several training seeds per variant -------------------------------------------------------


def test_one_seed_each_is_the_paired_bootstrap_draw_for_draw() -> None:
    rng = np.random.default_rng(5)
    a, b = rng.normal(0.3, 0.1, 33), rng.normal(0.3, 0.1, 33)
    assert seed_bootstrap(a[None], b[None], 3000, 0.9, 4) == paired_bootstrap(a, b, 3000, 0.9, 4)


def test_two_level_bootstrap_matches_a_straightforward_loop() -> None:
    rng = np.random.default_rng(8)
    run = rng.normal(0.30, 0.1, (3, 20)) + rng.normal(0, 0.05, (3, 1))  # 3 seeds with their own offsets
    ref = rng.normal(0.32, 0.1, (2, 20))
    ours = seed_bootstrap(run, ref, samples=1500, confidence=0.9, seed=2)
    draw = np.random.default_rng(2)
    means = []
    for _ in range(
        1500
    ):  # the same draws, one resample at a time: units, then run seeds, then reference seeds
        units = draw.integers(0, 20, 20)
        seeds_run = draw.integers(0, 3, 3)
        seeds_ref = draw.integers(0, 2, 2)
        means.append(run[seeds_run][:, units].mean() - ref[seeds_ref][:, units].mean())
    # Chunked draws consume the stream in another order, so compare distributions, not draws.
    assert ours.low == pytest.approx(np.quantile(means, 0.05), abs=0.01)
    assert ours.high == pytest.approx(np.quantile(means, 0.95), abs=0.01)
    assert ours.mean == pytest.approx(run.mean() - ref.mean(), abs=1e-12)
    assert (ours.n, ours.seeds, ours.reference_seeds) == (20, 3, 2)


def test_seed_noise_widens_the_interval_and_one_lucky_seed_is_not_a_finding() -> None:
    rng = np.random.default_rng(0)
    ref = np.repeat(rng.uniform(0.2, 0.4, (1, 40)), 3, axis=0)  # the reference's seeds agree
    # The run's images are each 0.03 better on average, but only because seed 0 is 0.09 better.
    run = ref[[0]] + np.array([[-0.09], [0.0], [0.0]]) + rng.normal(0, 0.002, (3, 40))
    images_only = paired_bootstrap(run.mean(axis=0), ref.mean(axis=0), samples=4000)
    both = seed_bootstrap(run, ref, samples=4000)
    assert images_only.excludes_zero  # over images alone the 0.03 looks certain ...
    assert not both.excludes_zero  # ... over seeds too it is not
    assert both.high - both.low > 5 * (images_only.high - images_only.low)
    assert both.mean == pytest.approx(images_only.mean)


def test_seed_bootstrap_rejects_runs_over_different_units() -> None:
    with pytest.raises(ValueError, match="same units"):
        seed_bootstrap(np.ones((2, 5)), np.ones((1, 6)))


def test_statistics_over_seed_groups_and_their_spread() -> None:
    frames = [f"{i:06d}_10" for i in range(25)]
    rng = np.random.default_rng(3)
    base = rng.uniform(0.2, 0.4, 25)
    tables = {"full": {}, "roi": {}}
    offsets = {
        "ssim/seed0": 0.0,
        "ssim/seed1": 0.01,
        "msssim/seed0": -0.04,
        "msssim/seed1": -0.06,
        "prior": 0.1,
    }
    for run, off in offsets.items():
        tables["full"][run] = _table(frames, base + off)
        tables["roi"][run] = _table(frames, base + off).pipe(_as_rois)
    groups = {
        "ssim": ["ssim/seed0", "ssim/seed1"],
        "msssim": ["msssim/seed0", "msssim/seed1"],
        "prior": ["prior"],
    }
    stats = paired_statistics(tables, groups, CompareConfig(bootstrap_samples=500), [80.0])
    d = stats["full"]["cap80"]["msssim"]["abs_rel"]
    assert d["mean"] == pytest.approx(-0.055) and (d["seeds"], d["reference_seeds"], d["n"]) == (2, 2, 25)
    # Two seeds per side, resampled: the extremes -0.06 - 0.01 and -0.04 - 0.0 each come up in
    # 1/16 of the resamples (> 2.5 %), so they are the interval's ends.
    assert d["low"] == pytest.approx(-0.07) and d["high"] == pytest.approx(-0.04)
    assert stats["full"]["cap80"]["prior"]["abs_rel"]["seeds"] == 1

    metrics = {
        "full": {
            r: {"cap80": {m: float(np.mean(base + off)) for m in METRICS}} for r, off in offsets.items()
        },
        "roi": {
            r: {"cap80": {"overall": {m: float(np.mean(base + off)) for m in METRICS}}}
            for r, off in offsets.items()
        },
    }
    spread = seed_spread(metrics, groups, ["cap80"])
    s = spread["full"]["cap80"]["msssim"]["abs_rel"]
    assert s["mean"] == pytest.approx(np.mean(base) - 0.05)
    assert s["sd"] == pytest.approx(np.std([-0.04, -0.06], ddof=1))
    assert list(s["runs"]) == ["msssim/seed0", "msssim/seed1"]
    assert spread["full"]["cap80"]["prior"]["abs_rel"]["sd"] is None


def test_runs_are_averaged_leaf_by_leaf() -> None:
    a = {
        "cap80": {"overall": {"abs_rel": 0.2, "count": 10}, "by_class": {"car": {"abs_rel": 0.1}}},
        "images": 40,
        "note": None,
    }
    b = {
        "cap80": {"overall": {"abs_rel": 0.4, "count": 10}, "by_class": {"car": {"abs_rel": 0.3}}},
        "images": 40,
        "note": None,
    }
    mean = _mean_over_runs([a, b])
    assert mean["cap80"]["overall"] == {"abs_rel": pytest.approx(0.3), "count": 10}
    assert mean["cap80"]["by_class"]["car"]["abs_rel"] == pytest.approx(0.2)
    assert mean["images"] == 40 and isinstance(mean["images"], int) and mean["note"] is None
    with pytest.raises(DataError, match="different entries"):
        _mean_over_runs([a, {**b, "extra": 1}])


def test_comparison_of_several_seeds_says_so_and_shows_the_spread() -> None:
    block = {m: 0.3 for m in METRICS}
    suites = {
        "full": {r: {"cap80": block} for r in ("ssim", "msssim")},
        "roi": {r: {"cap80": {"overall": {**block, "count": 5}, "by_class": {}}} for r in ("ssim", "msssim")},
        "gradients": {
            r: {
                "cap80": {
                    "overall": {f"pred_{g}": 1.0 for g in ("sobel_x", "sobel_y", "laplacian")},
                    "dense_gt": {"overall": {}},
                }
            }
            for r in ("ssim", "msssim")
        },
    }
    entry = {m: {"mean": 0.3, "sd": 0.0125, "runs": {}} for m in METRICS}
    spread = {s: {"cap80": {"ssim": entry, "msssim": entry}} for s in ("full", "roi")}
    result, md = build_comparison(
        comparison_data(suites, ["ssim", "msssim"], [], seeds=[0, 1, 2], spread=spread)
    )
    assert "mean of 3 training runs (seeds 0, 1, 2)" in md
    assert md.count("Seed-to-seed spread") == 2 and "| msssim | 0.3000 ± 0.0125 |" in md
    assert result["seeds"] == [0, 1, 2] and result["seed_spread"] is spread
    _, one = build_comparison(comparison_data(suites, ["ssim", "msssim"], [], seeds=[0], spread=spread))
    assert "Seed-to-seed" not in one and "One training run per variant (seed 0)" in one


# --- the cluster bootstrap: ROIs drawn by their frames --------------------------------------------


def test_a_cluster_draw_matches_a_straightforward_loop() -> None:
    """Each draw picks frames with replacement and averages every ROI of the picked frames."""
    rng = np.random.default_rng(5)
    frames = np.repeat(np.arange(9), rng.integers(1, 6, 9))  # 9 frames of 1 to 5 ROIs
    a, b = rng.normal(0.3, 0.1, len(frames)), rng.normal(0.3, 0.1, len(frames))
    ours = seed_bootstrap(a[None], b[None], samples=2000, confidence=0.9, seed=4, clusters=frames)
    draw = np.random.default_rng(4)
    members = [np.flatnonzero(frames == f) for f in range(9)]
    means = [
        np.mean((a - b)[np.concatenate([members[f] for f in draw.integers(0, 9, 9)])]) for _ in range(2000)
    ]
    assert ours.low == pytest.approx(np.quantile(means, 0.05), abs=1e-12)
    assert ours.high == pytest.approx(np.quantile(means, 0.95), abs=1e-12)
    assert (ours.n, ours.clusters) == (len(frames), 9)


def test_one_unit_per_cluster_is_the_unit_bootstrap_draw_for_draw() -> None:
    rng = np.random.default_rng(6)
    run, ref = rng.normal(0.3, 0.1, (3, 30)), rng.normal(0.31, 0.1, (3, 30))
    for paired in (False, True):
        plain = seed_bootstrap(run, ref, samples=1000, paired=paired)
        single = seed_bootstrap(run, ref, samples=1000, paired=paired, clusters=np.arange(30))
        assert (single.low, single.high, single.mean) == (plain.low, plain.high, plain.mean)
        assert (plain.clusters, single.clusters) == (None, 30)


def test_copies_of_a_frame_count_once() -> None:
    """Five identical ROIs per frame carry one frame's evidence: the interval is the frames' own."""
    frames = np.random.default_rng(7).normal(-0.02, 0.05, 8)
    alone = paired_bootstrap(frames, np.zeros(8), samples=2000)
    copies = np.repeat(frames, 5)
    drawn = seed_bootstrap(copies[None], np.zeros((1, 40)), samples=2000, clusters=np.repeat(np.arange(8), 5))
    as_units = paired_bootstrap(copies, np.zeros(40), samples=2000)
    assert (drawn.low, drawn.high) == pytest.approx((alone.low, alone.high), abs=1e-12)
    assert as_units.high - as_units.low < 0.6 * (drawn.high - drawn.low)  # 40 "units" look surer


def test_cluster_labels_must_be_one_per_unit() -> None:
    with pytest.raises(ValueError, match="one cluster label per unit"):
        seed_bootstrap(np.zeros((1, 4)), np.zeros((1, 4)), clusters=np.arange(3))


def test_the_roi_suite_is_drawn_by_frame() -> None:
    """paired_statistics draws the ROI suite's frames (the tables' image column), the full suite's
    images; each difference counts its frames."""
    rng = np.random.default_rng(9)
    roi = pd.DataFrame({"roi": range(12), "image": np.repeat(["a", "b", "c", "d"], 3), "cap": 80.0})
    full = pd.DataFrame({"frame": list("abcd"), "cap": 80.0})
    tables: dict = {"full": {}, "roi": {}}
    for run in ("ssim/seed0", "msssim/seed0"):
        tables["roi"][run] = roi.assign(**{m: rng.uniform(0.1, 0.5, 12) for m in METRICS})
        tables["full"][run] = full.assign(**{m: rng.uniform(0.1, 0.5, 4) for m in METRICS})
    groups = {"ssim": ["ssim/seed0"], "msssim": ["msssim/seed0"]}
    stats = paired_statistics(tables, groups, CompareConfig(bootstrap_samples=200), [80.0], {"msssim": None})
    roi_d, full_d = stats["roi"]["cap80"]["msssim"]["abs_rel"], stats["full"]["cap80"]["msssim"]["abs_rel"]
    assert (roi_d["n"], roi_d["clusters"]) == (12, 4)
    assert (full_d["n"], full_d["clusters"]) == (4, None)
    a, b = tables["roi"]["msssim/seed0"]["abs_rel"], tables["roi"]["ssim/seed0"]["abs_rel"]
    by_frame = seed_bootstrap(a.to_numpy()[None], b.to_numpy()[None], 200, clusters=roi["image"].to_numpy())
    assert (roi_d["low"], roi_d["high"]) == (by_frame.low, by_frame.high)
