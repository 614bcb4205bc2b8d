"""The optimum in the pipeline: the compare section's data and rendering with known inputs, the
stage helpers (weights, frames, run names) and the cost-curve summary and figure."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from msdepth.config.params import params_from_dict
from msdepth.errors import ConfigError, DataError
from msdepth.optimum.frames import (
    checked_weight,
    cost_summary,
    first_frames,
    optimum_runs,
    sweep_frames,
)
from msdepth.optimum.solver import COST_SCALES
from msdepth.pipeline.paths import optimum_run
from msdepth.reporting.compare import build_comparison, comparison_data, optimum_data
from msdepth.reporting.figures import cost_curve_figure, read_cost_curves

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


RUNS = {"optimum ssim w10": "optimum/ssim/w10.0", "optimum ssim w3": "optimum/ssim/w3.0"}
OPT_SUITES = {
    "full": {"optimum/ssim/w10.0": _full(0.1), "optimum/ssim/w3.0": _full(0.15, images=2)},
    "roi": {"optimum/ssim/w10.0": _roi(0.12, 0.11, 0.09), "optimum/ssim/w3.0": _roi(0.2, 0.21, 0.19)},
}
FULL_DIFF = {"abs_rel": _difference(-0.2, -0.3, -0.1), "a1": _difference(0.2, -0.1, 0.4)}
ROI_DIFF = {"abs_rel": _difference(-0.1, -0.2, 0.05), "a1": _difference(0.1, 0.0, 0.2)}
STATS = {
    "reference": "ssim",
    "full": {"cap80": {"optimum ssim w10": FULL_DIFF}},
    "roi": {"cap80": {"optimum ssim w10": ROI_DIFF}},
}


def test_optimum_data_collects_each_runs_numbers_and_its_differences():
    data = optimum_data(OPT_SUITES, RUNS, STATS, "cap80")
    w10 = data["runs"]["optimum ssim w10"]
    assert (w10["images"], w10["abs_rel"], w10["a1"]) == (3, 0.1, 0.9)
    assert (w10["roi_abs_rel"], w10["by_class"], w10["mask_abs_rel"]) == (0.12, {"car": 0.11}, 0.09)
    assert data["runs"]["optimum ssim w3"]["images"] == 2
    assert set(data["differences"]) == {"optimum ssim w10"}  # the sweep's subset weights: no pairing
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
    data = optimum_data(OPT_SUITES, RUNS, STATS, "cap80")
    result, md = build_comparison(
        comparison_data(_trained_suites(), ["ssim", "msssim"], ["prior"], optimum=data)
    )
    section = md[md.index("# The losses' own optimum (no network)") :]
    # The trained runs and the baselines were scored on every frame: their count stands beside them.
    assert "| ssim | 5 | 0.3000 | 0.7000 | 0.3500 | 0.3300 |" in section
    assert "| prior | 5 | 0.5000 | 0.5000 | 0.5000 | 0.5000 |" in section
    assert "| optimum ssim w10 | 3 | 0.1000 | 0.9000 | 0.1200 | 0.0900 |" in section
    assert "| optimum ssim w3 | 2 | 0.1500 |" in section
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
    assert list(sweep_frames(params, index, 3.0)["frame"]) == list(index["frame"][:4])
    assert len(first_frames(index, 0)) == 12 and list(first_frames(index, 2)["frame"]) == [
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


def test_cost_summary_and_its_figure(tmp_path: Path):
    log_s = np.log(COST_SCALES)
    curves = {"car": [log_s**2, 2 * log_s**2], "glass": [(log_s + np.log(2)) ** 2]}
    summary = cost_summary(curves)
    assert summary["classes"]["car"]["s_min"] == pytest.approx(1.0) and summary["classes"]["car"]["rois"] == 2
    assert summary["classes"]["glass"]["s_min"] == pytest.approx(0.5)
    assert summary["mean_curves"]["car"] == pytest.approx(list(1.5 * log_s**2))
    (tmp_path / "ssim.json").write_text(json.dumps(summary))
    read = read_cost_curves(tmp_path, ["ssim"])
    out = cost_curve_figure(read, tmp_path / "cost_curves.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(DataError, match="msssim.json: cannot read the cost curves"):
        read_cost_curves(tmp_path, ["msssim"])


def test_the_optimum_stage_lists_every_optimum_key_it_reads_and_no_training_weight():
    """Changing any optimiser key re-runs the optimum; cost_frames (the cost curves') and
    loss.smoothness_weight (replaced by the optimum's own) do not."""
    import dataclasses

    import yaml

    from msdepth.config.params import OptimumConfig

    stages = yaml.safe_load((Path(__file__).resolve().parents[1] / "dvc.yaml").read_text())["stages"]
    listed = set(stages["optimum"]["params"])
    expected = {f"optimum.{f.name}" for f in dataclasses.fields(OptimumConfig)} - {"optimum.cost_frames"}
    assert {p for p in listed if p.startswith("optimum")} == expected
    assert "loss" not in listed and "loss.smoothness_weight" not in listed and "${item.variant}" in listed
    assert "optimum.cost_frames" in stages["cost_curves"]["params"]


def test_the_cost_curves_of_a_rerun_are_the_same_bytes(tmp_path: Path):
    """issue 40: the stage's computation twice on a tiny rendered set writes identical files."""
    from msdepth.config.params import SyntheticConfig
    from msdepth.data import synthetic
    from msdepth.data.index import build_eval_index, write_eval_index
    from msdepth.optimum.frames import write_cost_curves

    root = tmp_path / "synthetic"
    synthetic.generate(
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
