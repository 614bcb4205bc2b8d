"""compare.md and compare.json name each variant's settings (its params section) where they differ
from the defaults, so that an experiment's tables say what it changed."""

from __future__ import annotations

from msdepth.analysis.comparison import changed_settings, comparison_data, settings_text, variant_settings
from msdepth.config.params import params_from_dict
from msdepth.evaluation.metrics import METRICS
from msdepth.evaluation.suites import NO_ROIS
from msdepth.reporting.comparison import _seed_resampling, build_comparison

DEFAULT_MSSSIM = {"kernel_size": 3, "levels": 4, "weights": "wang"}


def _suites(runs: dict[str, float]) -> dict:
    """Full-image metrics only (no ROIs): every metric of run r is runs[r]."""
    none = {"rois": 0, NO_ROIS: "no ROIs"}
    return {
        "full": {r: {"cap80": dict.fromkeys(METRICS, v), "images": 2} for r, v in runs.items()},
        "roi": dict.fromkeys(runs, none),
        "gradients": dict.fromkeys(runs, none),
    }


def test_variant_settings_are_each_variants_params_section():
    params = params_from_dict({"msssim": {"kernel_size": 7}, "variants": ["ssim", "msssim"]})
    assert variant_settings(params) == {
        "ssim": {"kernel_size": 3, "padding": "valid"},
        "msssim": {**DEFAULT_MSSSIM, "kernel_size": 7},
    }


def test_changed_settings_are_those_away_from_the_defaults():
    assert changed_settings("msssim", DEFAULT_MSSSIM) == {}
    assert changed_settings("msssim", {**DEFAULT_MSSSIM, "kernel_size": 7, "weights": "equal"}) == {
        "kernel_size": 7,
        "weights": "equal",
    }
    assert changed_settings(
        "mix", {"alpha": 0.5, "levels": 4, "sigma": 0.5, "kernel_size": 5, "weights": "ones"}
    ) == {"alpha": 0.5}


def test_settings_text_abbreviates_the_kernel_size():
    assert settings_text({"kernel_size": 7, "levels": 3, "weights": "wang"}) == "k=7, levels=3, weights=wang"
    assert settings_text({"alpha": 0.84, "sigma": 0.5}) == "alpha=0.84, sigma=0.5"
    assert settings_text({}) == ""


def test_compare_names_a_changed_kernel_size_in_the_rows_and_every_setting_in_the_header():
    settings = {
        "ssim": {"kernel_size": 3, "padding": "valid"},
        "msssim": {**DEFAULT_MSSSIM, "kernel_size": 7},
    }
    comparison = comparison_data(
        _suites({"ssim": 0.3, "msssim": 0.2}), ["ssim", "msssim"], [], settings=settings
    )
    result, md = build_comparison(comparison)
    lines = md.splitlines()
    assert (
        "Settings: ssim k=3, padding=valid; msssim k=7, levels=4, weights=wang "
        "(a row names where its variant differs from the defaults)." in lines
    )
    assert (
        "| msssim (k=7) | **0.2000** | **0.2000** | **0.2000** | **0.2000** | 0.2000 | 0.2000 | 0.2000 |"
        in lines
    )
    assert "| ssim | 0.3000 | 0.3000 | 0.3000 | 0.3000 | **0.3000** | **0.3000** | **0.3000** |" in lines
    assert result["settings"] == settings and list(result)[:4] == [
        "variants",
        "baselines",
        "seeds",
        "settings",
    ]
    assert comparison.label("msssim") == "msssim (k=7)" and comparison.settings_label("ssim") == "ssim"


def test_compare_at_the_defaults_states_the_kernel_once_and_keeps_the_row_names():
    settings = {"ssim": {"kernel_size": 3, "padding": "valid"}, "msssim": DEFAULT_MSSSIM}
    _, md = build_comparison(
        comparison_data(_suites({"ssim": 0.3, "msssim": 0.2}), ["ssim", "msssim"], [], settings=settings)
    )
    assert md.count("k=3") == 2 and "| msssim | **0.2000** |" in md and "(k=" not in md


def test_without_settings_compare_json_and_md_are_as_before():
    result, md = build_comparison(
        comparison_data(_suites({"ssim": 0.3, "msssim": 0.2}), ["ssim", "msssim"], [])
    )
    assert "settings" not in result and "Settings:" not in md and "| msssim | **0.2000** |" in md


def test_an_image_blind_run_keeps_its_settings_in_the_label():
    settings = {"msssim": {**DEFAULT_MSSSIM, "levels": 3}}
    dependence = {"msssim": {"image_blind": True}}
    comparison = comparison_data(
        _suites({"msssim": 0.2}), ["msssim"], [], dependence=dependence, settings=settings
    )
    assert comparison.label("msssim") == "msssim (levels=3) (image-blind)"


def test_every_table_with_rois_names_the_changed_kernel():
    """The ROI, per-class and gradient tables too: no row is left called plain ``msssim``."""
    suites = _suites({"ssim": 0.3, "msssim": 0.2})
    for run, v in (("ssim", 0.3), ("msssim", 0.2)):
        m = dict.fromkeys(METRICS, v)
        suites["roi"][run] = {"cap80": {"overall": {**m, "count": 1}, "by_class": {"car": {**m, "count": 1}}}}
        g = {"pred_sobel_x": v, "pred_sobel_y": v, "pred_laplacian": v, "count": 1}
        dense = {"overall": {"count": 0}, "by_class": {}}
        suites["gradients"][run] = {"cap80": {"overall": g, "by_class": {}, "dense_gt": dense}}
    settings = {"msssim": {**DEFAULT_MSSSIM, "kernel_size": 7}}
    _, md = build_comparison(comparison_data(suites, ["ssim", "msssim"], [], settings=settings))
    rows = [line.split(" |")[0] for line in md.splitlines() if line.startswith("| msssim")]
    assert rows == ["| msssim (k=7)"] * 4  # full image, ROI, ROI per class, gradients


def test_the_method_line_says_seed_pairs_only_where_the_variants_pair():
    """compare.md's statistics line names the resampling that was done: seed pairs jointly for a
    paired variant, per variant (with the reason) for an unpaired one, nothing for one seed."""
    both = {"pairing": {"msssim": None, "constant": "a baseline is one deterministic run"}}
    text = _seed_resampling(both, ["ssim", "msssim"], several=True)
    assert "jointly with seed pairs for msssim" in text and "per variant" not in text
    apart = {"pairing": {"msssim": "the two variants were trained with different seeds"}}
    text = _seed_resampling(apart, ["ssim", "msssim"], several=True)
    assert "pairs" not in text.split("(")[0] and "per variant, seeds" in text and "different seeds" in text
    assert _seed_resampling(both, ["ssim", "msssim"], several=False) == ""
