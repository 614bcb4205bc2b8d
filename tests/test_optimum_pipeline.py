"""The optimum in the pipeline: the compare section's data and rendering with known inputs, the
stage helpers (weights, frames, run names) and the cost-curve summary and figure."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from msdepth.analysis.comparison import comparison_data, optimum_data
from msdepth.config.params import params_from_dict
from msdepth.errors import ConfigError, DataError
from msdepth.optimum.frames import (
    _first_frames,
    checked_weight,
    cost_summary,
    optimum_runs,
    sweep_frames,
)
from msdepth.optimum.solver import COST_SCALES
from msdepth.pipeline.paths import optimum_run
from msdepth.reporting.comparison import build_comparison
from msdepth.reporting.figures import _read_cost_curves, cost_curve_figure

METRICS = {"abs_rel": 0.2, "sq_rel": 0.2, "rmse": 0.2, "rmse_log": 0.2, "a1": 0.8, "a2": 0.8, "a3": 0.8}


def _full(abs_rel: float, images: int = 3) -> dict:
    return {"cap80": {**METRICS, "abs_rel": abs_rel, "a1": 1 - abs_rel}, "images": images}


def _roi(abs_rel: float, car: float, mask: float) -> dict:
    m = {**METRICS, "abs_rel": abs_rel, "count": 2}
    exact = {**m, "abs_rel": mask}
    masks = {"cap80": {"overall": exact, "by_class": {"car": exact}}, "rois": 2, "excluded_rois": 0}
    return {"cap80": {"overall": m, "by_class": {"car": {**m, "abs_rel": car}}}, "masks": masks}


def _difference(mean: float, low: float, high: float) -> dict:
    return {"mean": mean, "low": low, "high": high, "n": 3, "seeds": 1, "reference_seeds": 1,
            "excludes_zero": low > 0 or high < 0}  # fmt: skip


def _stereo(abs_rel: float, d1: float, epe: float) -> dict:
    full = _full(abs_rel)
    full["cap80"].update(d1=d1, epe=epe)
    return full


RUNS = {
    "optimum ssim w10": "optimum/ssim/w10.0",
    "optimum ssim w3": "optimum/ssim/w3.0",
    "SGBM": "optimum/sgbm",
}
OPT_SUITES = {
    "full": {
        "optimum/ssim/w10.0": _stereo(0.1, 0.1234, 1.5),
        "optimum/ssim/w3.0": _full(0.15, images=2),
        "optimum/sgbm": _stereo(0.05, 0.034, 0.876),
    },
    "roi": {
        "optimum/ssim/w10.0": _roi(0.12, 0.11, 0.09),
        "optimum/ssim/w3.0": _roi(0.2, 0.21, 0.19),
        "optimum/sgbm": _roi(0.07, 0.06, 0.05),
    },
}
FULL_DIFF = {"abs_rel": _difference(-0.2, -0.3, -0.1), "a1": _difference(0.2, -0.1, 0.4)}
ROI_DIFF = {"abs_rel": _difference(-0.1, -0.2, 0.05), "a1": _difference(0.1, 0.0, 0.2)}
STATS = {
    "reference": "ssim",
    "full": {"cap80": {"optimum ssim w10": FULL_DIFF, "SGBM": FULL_DIFF}},
    "roi": {"cap80": {"optimum ssim w10": ROI_DIFF, "SGBM": ROI_DIFF}},
}
SKIPPED = {"SGM (mix cost)": "variant mix has no per-pixel cost: no cost volume to match on"}


def test_optimum_data_collects_each_runs_numbers_and_its_differences():
    data = optimum_data(OPT_SUITES, RUNS, STATS, "cap80", SKIPPED)
    w10 = data["runs"]["optimum ssim w10"]
    assert (w10["images"], w10["abs_rel"], w10["a1"], w10["d1"], w10["epe"]) == (3, 0.1, 0.9, 0.1234, 1.5)
    assert "d1" not in data["runs"]["optimum ssim w3"]  # metrics written before D1: none shown
    assert data["skipped"] == SKIPPED
    assert (w10["roi_abs_rel"], w10["by_class"], w10["mask_abs_rel"]) == (0.12, {"car": 0.11}, 0.09)
    assert data["runs"]["optimum ssim w3"]["images"] == 2
    # the sweep's subset weights: no pairing; the matchers see every frame
    assert set(data["differences"]) == {"optimum ssim w10", "SGBM"}
    assert data["differences"]["optimum ssim w10"]["full"]["abs_rel"]["mean"] == -0.2
    assert data["reference"] == "ssim"


def _trained_suites() -> dict:
    grad = {
        "cap80": {
            "overall": {"pred_sobel_x": 1, "pred_sobel_y": 1, "pred_laplacian": 1},
            "dense_gt": {"overall": {}},
        }
    }
    runs = {"ssim": (0.3, 0.35, 0.33), "msssim": (0.25, 0.3, 0.28), "prior": (0.5, 0.5, 0.5)}
    return {
        "full": {r: {"images": 5, "cap80": {**METRICS, "abs_rel": v[0], "a1": 1 - v[0]}}
                 for r, v in runs.items()},
        "roi": {r: _roi(v[1], v[1], v[2]) for r, v in runs.items()},
        "gradients": {r: grad for r in runs},
    }  # fmt: skip


def test_the_optimum_section_shows_optimum_trained_runs_and_baselines_side_by_side():
    data = optimum_data(OPT_SUITES, RUNS, STATS, "cap80", SKIPPED)
    result, md = build_comparison(
        comparison_data(_trained_suites(), ["ssim", "msssim"], ["prior"], optimum=data)
    )
    section = md[md.index("# The losses' own optimum (no network)") :]
    # The trained runs and the baselines were scored on every frame: their count stands beside them.
    # D1 in %, EPE in px; "–" where a suite has neither (metrics written before they were added).
    assert "| ssim | 5 | 0.3000 | 0.7000 | – | – | 0.3500 | 0.3300 |" in section
    assert "| prior | 5 | 0.5000 | 0.5000 | – | – | 0.5000 | 0.5000 |" in section
    assert "| optimum ssim w10 | 3 | 0.1000 | 0.9000 | 12.3 | 1.50 | 0.1200 | 0.0900 |" in section
    assert "| optimum ssim w3 | 2 | 0.1500 |" in section
    assert "| SGBM | 3 | 0.0500 | 0.9500 | 3.4 | 0.88 | 0.0700 | 0.0500 |" in section
    assert "SGM (mix cost): skipped (variant mix has no per-pixel cost" in section
    assert "| SGBM | -0.200 [-0.300, -0.100] * |" in section
    # * only where the interval excludes 0; the optimum has no seed: the interval covers the images.
    assert "| optimum ssim w10 | -0.200 [-0.300, -0.100] * | +0.200 [-0.100, +0.400] |" in section
    assert "| -0.100 [-0.200, +0.050] | +0.100 [+0.000, +0.200] |" in section
    assert "interval covers the choice of images" in section
    assert "| optimum ssim w10 | 0.1100 | 0.0900 |" in section  # per class: box, then exact mask
    assert result["optimum"]["runs"]["optimum ssim w3"]["abs_rel"] == 0.15


def test_no_optimum_no_section():
    _, md = build_comparison(comparison_data(_trained_suites(), ["ssim", "msssim"], ["prior"]))
    assert "own optimum" not in md


def test_weights_frames_and_run_names(tmp_path: Path):
    params = params_from_dict({})
    assert checked_weight(params, "10.0") == 10.0 and checked_weight(params, "30") == 30.0
    with pytest.raises(ConfigError, match="not in optimum.smoothness_sweep"):
        checked_weight(params, "7")
    with pytest.raises(ConfigError, match="not a number"):
        checked_weight(params, "ten")
    index = pd.DataFrame({"frame": [f"{i:06d}_10" for i in range(12)]})
    assert len(sweep_frames(params, index, 10.0)) == 12  # the default weight: every frame
    assert len(sweep_frames(params, index, 3.0)) == 12  # default sweep_frames 0: every weight, every frame
    cheap = params_from_dict({"optimum": {"sweep_frames": 4}})
    assert list(sweep_frames(cheap, index, 3.0)["frame"]) == list(index["frame"][:4])
    assert len(sweep_frames(cheap, index, 10.0)) == 12
    assert len(_first_frames(index, 0)) == 12 and list(_first_frames(index, 2)["frame"]) == [
        "000000_10",
        "000001_10",
    ]
    for variant, weight in (
        ("ssim", "3.0"),
        ("ssim", "10"),
        ("ssim", "30.0"),
        ("msssim", "3"),
        ("msssim", "10.0"),
    ):
        path = tmp_path / "full" / optimum_run(variant, weight)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.with_suffix(".json").write_text("{}")
    with pytest.raises(DataError, match="msssim: no optimum at weight 30"):
        optimum_runs(params, tmp_path)
    (tmp_path / "full" / "optimum" / "msssim" / "w30.json").write_text("{}")
    runs = optimum_runs(params, tmp_path)
    assert (
        runs["optimum ssim w10"] == "optimum/ssim/w10" and runs["optimum msssim w30"] == "optimum/msssim/w30"
    )
    assert len(runs) == 6


def test_cost_summary_and_its_figure(tmp_path: Path, monkeypatch):
    log_s = np.log(COST_SCALES)
    curves = {"car": [log_s**2, 2 * log_s**2], "glass": [(log_s + np.log(2)) ** 2]}
    summary = cost_summary(curves)
    assert summary["classes"]["car"]["s_min"] == pytest.approx(1.0) and summary["classes"]["car"]["rois"] == 2
    assert summary["classes"]["glass"]["s_min"] == pytest.approx(0.5)
    assert summary["mean_curves"]["car"] == pytest.approx(list(1.5 * log_s**2))
    (tmp_path / "ssim.json").write_text(json.dumps(summary))
    read = _read_cost_curves(tmp_path, ["ssim"])
    out = cost_curve_figure(read, tmp_path / "cost_curves.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # Issue 68: each curve relative to its own minimum (the losses' scales differ), the dotted minima named
    import msdepth.reporting.figures as figures

    scaled = {
        "ssim": read["ssim"],
        "msssim": {**read["ssim"], "mean_curves": {"car": list(100 + 50 * log_s**2)}},
    }
    monkeypatch.setattr(figures, "_save", lambda fig, path: fig)
    car = cost_curve_figure(scaled, tmp_path / "x.png").axes[0]
    assert [min(line.get_ydata()) for line in car.lines if line.get_label() in scaled] == [0.0, 0.0]
    labels = car.get_legend_handles_labels()[1]
    assert {"ssim's minimum", "msssim's minimum", "GT (s = 1)"} <= set(labels)
    with pytest.raises(DataError, match="msssim.json: cannot read the cost curves"):
        _read_cost_curves(tmp_path, ["msssim"])


def test_the_optimum_stage_lists_every_optimum_key_it_reads_and_no_training_weight():
    """Changing any optimiser key re-runs the optimum; cost_frames (the cost curves'), set_weights
    (the extra sets') and loss.smoothness_weight (replaced by the optimum's own) do not."""
    import dataclasses

    import yaml

    from msdepth.config.params import OptimumConfig

    stages = yaml.safe_load((Path(__file__).resolve().parents[1] / "dvc.yaml").read_text())["stages"]
    listed = set(stages["optimum"]["params"])
    expected = {f"optimum.{f.name}" for f in dataclasses.fields(OptimumConfig)}
    expected -= {"optimum.cost_frames", "optimum.set_weights", "optimum.jobs"}  # jobs: the extra sets'
    assert {p for p in listed if p.startswith("optimum")} == expected
    assert "train.device" in listed  # where its refinement runs
    assert "loss" not in listed and "loss.smoothness_weight" not in listed and "${item.variant}" in listed
    assert "optimum.cost_frames" in stages["cost_curves"]["params"]


def test_the_cost_curves_of_a_rerun_are_the_same_bytes(tmp_path: Path):
    """issue 40: the stage's computation twice on a tiny rendered set writes identical files."""
    from msdepth import render
    from msdepth.config.params import SyntheticConfig
    from msdepth.data.eval_index import build_eval_index, write_eval_index
    from msdepth.optimum.frames import write_cost_curves

    root = tmp_path / "synthetic"
    render.generate(
        SyntheticConfig(seed=3, drives=1, train_pairs=1, eval_frames=2, height=96, width=320),
        root,
        progress=False,
        workers=1,
        lidar=False,
    )
    k2015 = root / "kitti2015"
    write_eval_index(tmp_path / "eval.csv", build_eval_index(k2015, k2015 / "test_files.txt", "disp_noc_0"))
    params = params_from_dict({"optimum": {"cost_frames": 2, "threads": 1}})
    outs = [tmp_path / "a.json", tmp_path / "b.json"]
    for out in outs:
        write_cost_curves(params, "ssim", tmp_path / "eval.csv", root / "rois.csv", out)
    assert json.loads(outs[0].read_text())["classes"]  # some box had dense GT
    assert outs[0].read_bytes() == outs[1].read_bytes()


# ----------------------------------------------------------------------------- the matchers' stage


@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> tuple[Path, object]:
    """A tiny rendered set (2 evaluation frames, 48 x 160) with its index and ROIs, as the data,
    index and rois stages write them, and the params that made it."""
    from conftest import stage

    from msdepth.render import generate

    root = tmp_path_factory.mktemp("match")
    raw = {
        "data": {
            "height": 32,
            "width": 96,
            "synthetic": {
                "seed": 3,
                "drives": 1,
                "train_pairs": 1,
                "eval_frames": 2,
                "height": 48,
                "width": 160,
            },
        },
        "msssim": {"levels": 3},
        "mix": {"levels": 3},
        "variants": ["ssim", "mix"],
        "optimum": {"start": "sgbm", "threads": 1},  # mix: no per-pixel cost for the cost start
    }
    params = params_from_dict(raw)
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(root)
        generate(params.data.synthetic, Path(params.data.root), progress=False, workers=1)
        stage("index").index(params)
        stage("rois").rois(params)
    return root, params


def test_the_match_stage_scores_sgm_and_sgbm_and_skips_a_variant_without_a_cost(rendered, monkeypatch):
    """stages/match.py: SGM on ssim's cost and SGBM through every suite as runs optimum/match/ssim and
    optimum/sgbm (metrics only, D1 and EPE in the full suite); mix, with no per-pixel cost, leaves
    skipped metrics that compare lists with the reason; an unknown matcher is one line."""
    from conftest import stage

    from msdepth.evaluation.baselines import skipped_reason
    from msdepth.optimum.frames import matcher_runs
    from msdepth.pipeline.paths import HEADLINE, METRICS, SGBM_RUN, headline_path, match_run, suite_path

    root, params = rendered
    monkeypatch.chdir(root)
    match = stage("match").match
    for matcher in ("ssim", "sgbm", "mix"):
        match(params, matcher)
    assert match_run("ssim") == "optimum/match/ssim" and match_run("sgbm") == SGBM_RUN == "optimum/sgbm"
    for run in (match_run("ssim"), SGBM_RUN):
        full = json.loads(suite_path("full", run).read_text())
        assert full["images"] == 2 and full["cap80"]["abs_rel"] < 0.5, run  # a rendered scene: matched
        assert 0 <= full["cap80"]["d1"] < 0.5 and 0 < full["cap80"]["epe"] < 5, run
        table = pd.read_csv(suite_path("full", run, ".csv"))
        assert {"d1", "epe"} <= set(table.columns) and len(table) == 2 * len(params.eval.caps)
        assert suite_path("roi", run).is_file() and suite_path("gradients", run, ".csv").is_file()
        assert "d1" not in json.loads(headline_path("full", run).read_text())  # dvc metrics show's width
        assert not (root / "outputs" / run).exists()
    assert skipped_reason(METRICS, match_run("mix"), ["full", "roi"]) == (
        "variant mix has no per-pixel cost: no cost volume to match on"
    )
    assert "skipped" in json.loads(headline_path("roi", match_run("mix"), HEADLINE).read_text())
    assert not (METRICS / "gradients" / "optimum" / "match" / "mix.json").read_text().count("cap80")
    assert matcher_runs(params) == {
        "SGM (ssim cost)": "optimum/match/ssim",
        "SGM (mix cost)": "optimum/match/mix",
        "SGBM": "optimum/sgbm",
    }
    with pytest.raises(ConfigError, match="unknown variant 'msssim'"):
        match(params, "msssim")


def test_the_match_stages_list_what_they_read():
    """match@<variant> reads its variant's section and the cost's α; sgbm reads neither; both the
    evaluation keys of the suites and optimum.threads, and no optimiser key."""
    import yaml

    stages = yaml.safe_load((Path(__file__).resolve().parents[1] / "dvc.yaml").read_text())["stages"]
    suites = {"eval.caps", "eval.min_depth", "eval.mask_gt_beyond_cap", "eval.dense_gt_fraction"}
    assert set(stages["match"]["params"]) == {"optimum.threads", "loss.alpha", "${item.variant}", *suites}
    assert set(stages["sgbm"]["params"]) == {"optimum.threads", *suites}
    assert stages["sgbm"]["cmd"] == "python stages/match.py sgbm"
