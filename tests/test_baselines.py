"""The image-blind baselines: their training GT on the synthetic set (disp_02) and on KITTI-shaped
trees (Velodyne scans), frames of several sizes, drives without GT, and the stages around them."""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import kitti_mirror
import numpy as np
import pandas as pd
import pytest
from conftest import stage

from msdepth import render
from msdepth.config.params import SyntheticConfig, params_from_dict
from msdepth.data import kitti
from msdepth.evaluation import baselines
from msdepth.evaluation.results import SUITES
from msdepth.pipeline import paths as pipeline

SYN = SyntheticConfig(seed=5, drives=2, train_pairs=6, eval_frames=3, height=48, width=160)


@pytest.fixture(scope="module")
def trees(tmp_path_factory) -> tuple[Path, Path, dict[str, np.ndarray]]:
    """The renderer's tree and its KITTI-shaped mirror (with the depth each scan should give)."""
    tree = tmp_path_factory.mktemp("synthetic")
    render.generate(SYN, tree, progress=False, workers=1)
    mirror = tmp_path_factory.mktemp("mirror")
    expected = kitti_mirror.mirror_from_synthetic(tree, mirror)
    return tree, mirror, expected


def _lefts(root: Path) -> list[Path]:
    """Every training left image (the renderer's raw evaluation drive, which has scans but no
    disp_02, is no training drive: its frames are in no training split)."""
    eval_drive = f"_drive_{render.EVAL_DRIVE:04d}_sync"
    return sorted(p for p in (root / "raw").glob("*/*_sync/image_02/data/*.png") if eval_drive not in str(p))


def test_synthetic_gt_is_disp_02_as_before(trees) -> None:
    tree, _, _ = trees
    gt = baselines.training_gt(_lefts(tree), progress=False)
    assert gt.sources == {"disp_02": SYN.train_pairs} and gt.missing == {} and gt.resampled == 0
    for frac, left in zip(gt.maps, _lefts(tree), strict=True):
        disp = kitti.read_disparity(left.parents[2] / "disp_02" / "data" / left.name)
        np.testing.assert_array_equal(frac, np.where(disp > 0, disp / disp.shape[1], np.nan))


def test_kitti_gt_is_the_projected_scan_as_disparity(trees) -> None:
    """No disp_02: each frame's scan through the day's calibration, f·B/x as a fraction of width,
    with the focal and baseline the evaluation would use for that width (here from P_rect_02/03)."""
    _, mirror, expected = trees
    lefts = _lefts(mirror)
    gt = baselines.training_gt(lefts, progress=False)
    assert gt.sources == {"velodyne": SYN.train_pairs} and gt.maps.shape == (SYN.train_pairs, 48, 160)
    focal = render.focal_for_width(160)
    for frac, left in zip(gt.maps, lefts, strict=True):
        depth = expected[left.relative_to(mirror / "raw").as_posix()]
        assert np.count_nonzero(depth) > 100
        want = np.full(depth.shape, np.nan, dtype=np.float32)
        want[depth > 0] = focal * kitti.KITTI_BASELINE / depth[depth > 0] / 160
        np.testing.assert_allclose(frac, want, rtol=1e-6)


def _day(root: Path, date: str, width: int, height: int, focal: float, frames: int, seed: int) -> None:
    """A raw day of ``frames`` frames whose scans put random depths on random pixels."""
    k = np.array([[focal, 0, width / 2], [0, focal, height / 2], [0, 0, 1]])
    left, right = np.c_[k, np.zeros(3)], np.c_[k, [-focal * 0.54, 0, 0]]
    proj = {"00": left, "01": right, "02": left, "03": right}
    kitti_mirror.write_day_calib(
        root / date, kitti_mirror.cam_to_cam_text(proj, kitti_mirror.R_RECT_00, width, height)
    )
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(frames):
        depth = np.where(rng.random((height, width)) < 0.05, rng.uniform(3, 70, (height, width)), 0)
        scan, _ = kitti_mirror.scan_from_depth(depth, proj["02"], kitti_mirror.R_RECT_00, rng, density=1.0)
        image = np.zeros((height, width, 3), dtype=np.uint8)
        rows.append((image, image, scan))
    kitti_mirror.write_drive(root / date / f"{date}_drive_0001_sync", rows)


def test_days_of_different_sizes_meet_at_the_most_common_size(tmp_path: Path) -> None:
    """KITTI's days differ in image size; the maps are brought to the most common one, every sample
    kept (upsampled) and KITTI widths converted with Monodepth's focal table, as the evaluation does."""
    raw = tmp_path / "raw"
    _day(raw, "2011_09_26", 1242, 375, 700.0, 2, seed=0)  # P_rect_02's focal is not the table's
    _day(raw, "2011_09_28", 1224, 370, 707.0493, 1, seed=1)
    lefts = _lefts(tmp_path)
    gt = baselines.training_gt(lefts, progress=False)
    assert gt.maps.shape == (3, 375, 1242) and gt.resampled == 1
    small = baselines._GTReader().read(
        "velodyne", raw / "2011_09_28/2011_09_28_drive_0001_sync/velodyne_points/data/0000000000.bin"
    )
    assert small.shape == (370, 1224)
    resampled = gt.maps[2]
    assert np.count_nonzero(~np.isnan(resampled)) == np.count_nonzero(~np.isnan(small))
    np.testing.assert_array_equal(np.sort(resampled[~np.isnan(resampled)]), np.sort(small[~np.isnan(small)]))
    depth = kitti.velodyne_depth(
        raw / "2011_09_26/2011_09_26_drive_0001_sync/velodyne_points/data/0000000000.bin",
        kitti.read_raw_calib(raw / "2011_09_26"),
    )
    valid = depth > 0
    np.testing.assert_allclose(gt.maps[0][valid], 721.5377 * 0.54 / depth[valid] / 1242, rtol=1e-6)
    assert np.isnan(gt.maps[0][~valid]).all()
    prior = baselines._per_pixel_prior(gt.maps)
    assert prior.shape == (375, 1242) and np.isfinite(prior).all()


def test_resample_sparse_keeps_every_sample_or_the_nearest() -> None:
    frac = np.full((4, 6), np.nan, dtype=np.float32)
    frac[0, 0], frac[0, 1], frac[3, 5] = 0.1, 0.3, 0.2
    down = baselines._resample_sparse(frac, (2, 3))
    assert down[0, 0] == np.float32(0.3)  # two samples meet: the larger disparity (nearer) wins
    assert down[1, 2] == np.float32(0.2) and np.isnan(down).sum() == 4
    up = baselines._resample_sparse(frac, (8, 12))
    assert sorted(up[~np.isnan(up)].tolist()) == sorted(frac[~np.isnan(frac)].tolist())
    np.testing.assert_array_equal(baselines._resample_sparse(frac, (4, 6)), frac)


def test_drive_without_gt_is_counted_and_left_out(trees, tmp_path: Path) -> None:
    _, mirror, _ = trees
    shutil.copytree(mirror / "raw", tmp_path / "raw")
    bare = sorted((tmp_path / "raw").glob("*/*_sync"))[0]
    shutil.rmtree(bare / "velodyne_points")
    gt = baselines.training_gt(_lefts(tmp_path), progress=False)
    assert gt.missing == {str(bare): 3} and gt.sources == {"velodyne": 3} and len(gt.maps) == 3
    for drive in sorted((tmp_path / "raw").glob("*/*_sync")):
        shutil.rmtree(drive / "velodyne_points", ignore_errors=True)
    gt = baselines.training_gt(_lefts(tmp_path), progress=False)
    assert gt.maps is None and sum(gt.missing.values()) == SYN.train_pairs


def test_memory_budget_takes_an_evenly_spaced_subset(trees) -> None:
    tree, _, _ = trees
    lefts = _lefts(tree)
    full = baselines.training_gt(lefts, progress=False)
    part = baselines.training_gt(lefts, progress=False, memory_budget=3 * 48 * 160 * 4)
    assert len(part.maps) == 3 and part.available == SYN.train_pairs
    np.testing.assert_array_equal(part.maps, full.maps[[0, 2, 5]])  # linspace(0, 5, 3), rounded


@pytest.mark.parametrize("frames", [7, 650])  # numpy takes another median path from 600 frames on
def test_per_pixel_prior_in_bands_is_the_median_of_the_whole_stack(frames: int) -> None:
    rng = np.random.default_rng(frames)
    gt = rng.uniform(0.01, 0.2, (frames, 37, 5)).astype(np.float32)
    gt[rng.random(gt.shape) < 0.7] = np.nan
    gt[:, 0, 0] = np.nan  # never valid: the global median
    with pytest.warns(RuntimeWarning):  # the all-NaN pixel
        want = np.nanmedian(gt, axis=0)
    want[np.isnan(want)] = np.nanmedian(gt)
    np.testing.assert_array_equal(baselines._per_pixel_prior(gt, rows_per_band=4), want.astype(np.float32))


# --------------------------------------------------------------------- the stages around them


def _kitti_project(root: Path, mirror: Path, tree: Path) -> object:
    """A project whose data.root data/kitti is the mirror, indexed, with ROIs and two fake trained runs."""
    shutil.copytree(mirror, root / "data" / "kitti")
    (root / "lists").mkdir()
    (root / "lists" / "train.txt").write_text((tree / "train_files.txt").read_text())
    (root / "lists" / "eval.txt").write_text((tree / "kitti2015" / "test_files.txt").read_text())
    params = params_from_dict(
        {
            "data": {
                "source": "kitti",
                "root": "data/kitti",
                "height": 32,
                "width": 96,
                "kitti": {
                    "train_split": "lists/train.txt",
                    "eval_split": "lists/eval.txt",
                    "roi_min_size": 4,
                    "roi_min_valid": 0.2,
                },
            },
            "train": {"seeds": [0]},
            "msssim": {"levels": 3},
            "eval": {"extra_sets": []},  # KITTI 2015's suites here; the Eigen set: test_kitti_pipeline
            "compare": {"bootstrap_samples": 200},
        }
    )
    stage("index").index(params)
    stage("rois").rois(params)
    rng = np.random.default_rng(0)
    for v in params.variants:
        run = pipeline.run_name(v, 0)
        pipeline.run_dir(run).mkdir(parents=True)
        np.save(
            pipeline.run_dir(run) / "disparities.npy", rng.uniform(0.01, 0.1, (3, 32, 96)).astype(np.float32)
        )
        stage("depth").depth(params, v, "0")
        for suite in SUITES:
            stage("evaluate").evaluate(params, suite, v, "0")
    return params


def test_kitti_stages_build_the_baselines_from_the_scans(trees, tmp_path: Path, monkeypatch) -> None:
    tree, mirror, _ = trees
    monkeypatch.chdir(tmp_path)
    params = _kitti_project(tmp_path, mirror, tree)
    stage("baselines").baselines(params)
    stage("compare").compare(params)
    md = Path("metrics/compare.md").read_text()
    assert "Baselines (image-blind, from training GT): constant, prior." in md and "Missing" not in md
    result = json.loads(Path("metrics/compare.json").read_text())
    assert set(result["full"]["cap80"]) == {"ssim", "msssim", "constant", "prior"}
    assert "missing_baselines" not in result


def test_no_training_gt_skips_the_baselines_and_compare_names_them(
    trees, tmp_path: Path, monkeypatch, caplog
) -> None:
    tree, mirror, _ = trees
    monkeypatch.chdir(tmp_path)
    params = _kitti_project(tmp_path, mirror, tree)
    drives = sorted(Path("data/kitti/raw").glob("*/*_sync"))
    for drive in drives:
        shutil.rmtree(drive / "velodyne_points")
    with caplog.at_level(logging.WARNING, logger="msdepth"):
        stage("baselines").baselines(params)
    lines = [r.getMessage() for r in caplog.records]
    for drive in drives:  # one line per drive, naming it
        assert sum(str(drive) in line and "left out" in line for line in lines) == 1
    assert any("constant and prior not built" in line for line in lines)
    for suite in SUITES:
        for run in baselines.BASELINES:
            marker = json.loads(Path(f"metrics/{suite}/{run}.json").read_text())
            assert "no training frame has GT" in marker[baselines.SKIPPED]
            assert pd.read_csv(f"metrics/{suite}/{run}.csv").columns.tolist() == [baselines.SKIPPED]
            if suite != "gradients":  # the declared DVC metrics exist too, or dvc repro would fail
                assert baselines.SKIPPED in json.loads(
                    Path(f"metrics/headline/{suite}/{run}.json").read_text()
                )
    stage("compare").compare(params)
    md = Path("metrics/compare.md").read_text()
    assert "Baselines (image-blind, from training GT): none." in md
    assert "Missing baselines (not built): constant, prior: no training frame has GT" in md
    assert "| prior |" not in md and "| ssim |" in md
    result = json.loads(Path("metrics/compare.json").read_text())
    assert set(result["missing_baselines"]) == {"constant", "prior"} and result["baselines"] == []
    assert set(result["full"]["cap80"]) == {"ssim", "msssim"}
