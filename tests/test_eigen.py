"""The Eigen split's evaluation: Garg's crop, GT in (min_depth, cap), median scaling, the GT
readers of every set, and the index builders of the extra sets.

The suite is checked against a transcription, written here from the anchors' published procedure
(Monodepth2 ``evaluate_depth.py``; the facts are in ``../shared/kitti/SOURCE.md``), image by image.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from test_kitti_lidar import P2, _random_cloud, _write_raw_calib

from msdepth.config.params import EvalConfig, params_from_dict
from msdepth.data import eval_sets, kitti
from msdepth.data.ground_truth import read_gt_depth
from msdepth.errors import ConfigError, DataError
from msdepth.evaluation.metrics import compute_errors, garg_crop_mask, median_scale
from msdepth.evaluation.suites import Frame, depth_maps, evaluate_full, load_frames
from msdepth.io import write_png

FOCAL, BASELINE = 721.5377, 0.54


def reference_eigen(gt_depths, pred_disps, cap, median_scaling=False, min_depth=1e-3):
    """Per image: disparity resized to the GT size (times its width), depth = f·B/disparity;
    mask = GT in (min_depth, cap) inside the crop rows [0.40810811 h, 0.99189189 h) and cols
    [0.03594771 w, 0.96405229 w) (int32-truncated); optional median scaling; clamp; metrics;
    mean over images."""
    rows, ratios = [], []
    for gt, disp in zip(gt_depths, pred_disps, strict=True):
        h, w = gt.shape
        pred = FOCAL * BASELINE / (w * cv2.resize(disp, (w, h), interpolation=cv2.INTER_LINEAR))
        mask = np.logical_and(gt > min_depth, gt < cap)
        t, b, left, r = np.array([0.40810811 * h, 0.99189189 * h, 0.03594771 * w, 0.96405229 * w]).astype(
            np.int32
        )
        crop = np.zeros(gt.shape)
        crop[t:b, left:r] = 1
        mask = np.logical_and(mask, crop)
        p, g = pred[mask], gt[mask]
        if median_scaling:
            ratio = np.median(g) / np.median(p)
            ratios.append(ratio)
            p = p * ratio
        p[p < min_depth] = min_depth
        p[p > cap] = cap
        rows.append(list(compute_errors(g, p).values()))
    return np.mean(rows, axis=0), np.array(ratios)


@pytest.mark.parametrize("shape", [(375, 1242), (370, 1224), (125, 414), (64, 192)])
def test_garg_crop_is_the_anchors_truncated_box(shape: tuple[int, int]) -> None:
    h, w = shape
    t, b, left, r = (int(v) for v in (0.40810811 * h, 0.99189189 * h, 0.03594771 * w, 0.96405229 * w))
    expected = np.zeros(shape, bool)
    expected[t:b, left:r] = True
    np.testing.assert_array_equal(garg_crop_mask(h, w), expected)
    if shape == (375, 1242):  # the published frame size: rows 153..370, cols 44..1196
        rows, cols = np.flatnonzero(expected.any(1)), np.flatnonzero(expected.any(0))
        assert (rows[0], rows[-1], cols[0], cols[-1]) == (153, 370, 44, 1196)


def test_garg_crop_rejects_an_empty_size() -> None:
    with pytest.raises(ValueError, match="positive"):
        garg_crop_mask(0, 10)


def test_median_scale_is_the_ratio_of_medians() -> None:
    gt, pred = np.array([1.0, 2.0, 3.0, 10.0]), np.array([2.0, 4.0, 6.0, 1.0])
    scaled, ratio = median_scale(gt, pred)
    assert ratio == pytest.approx(2.5 / 3.0)
    np.testing.assert_allclose(scaled, pred * 2.5 / 3.0)
    with pytest.raises(ValueError):
        median_scale(gt, pred[:2])


def _sparse_scene(seed: int = 0, n: int = 3, shape=(375, 1242)):
    rng = np.random.default_rng(seed)
    gts, disps = [], []
    for _ in range(n):
        gt = rng.uniform(0.5, 110.0, shape).astype(np.float32)  # some beyond each cap, some near 0
        gt[rng.random(shape) < 0.9] = 0  # LiDAR-sparse
        gts.append(gt)
        disps.append(rng.uniform(0.004, 0.3, (64, 192)).astype(np.float32))
    return gts, np.stack(disps)


def _eigen_frames(gts):
    return [
        Frame(f"f{i}", gt, FOCAL, BASELINE, crop=garg_crop_mask(*gt.shape), gt_in_range=True)
        for i, gt in enumerate(gts)
    ]


@pytest.mark.parametrize("median_scaling", [False, True])
def test_eigen_full_suite_matches_the_transcription(median_scaling: bool) -> None:
    gts, disps = _sparse_scene()
    frames = _eigen_frames(gts)
    cfg = EvalConfig()
    summary, table = evaluate_full(depth_maps(disps, frames), frames, cfg, median_scaling=median_scaling)
    for cap in cfg.caps:
        ref, ratios = reference_eigen(gts, disps, cap, median_scaling)
        ours = [
            summary[f"cap{cap:g}"][k] for k in ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")
        ]
        np.testing.assert_allclose(ours, ref, rtol=1e-5, atol=1e-6)
        if median_scaling:
            spread = summary[f"cap{cap:g}"]["median_scaling"]
            assert spread["ratio_median"] == pytest.approx(np.median(ratios), rel=1e-6)
            assert spread["ratio_std_over_median"] == pytest.approx(
                ratios.std() / np.median(ratios), rel=1e-6
            )
        else:
            assert "median_scaling" not in summary[f"cap{cap:g}"]
    assert len(table) == len(frames) * len(cfg.caps)


def test_without_the_crop_and_range_the_numbers_change() -> None:
    """The crop and the GT range are what make it the Eigen evaluation: dropping either moves the
    result (so a suite that ignored them could not pass the test above by luck)."""
    gts, disps = _sparse_scene(1)
    eigen = _eigen_frames(gts)
    plain = [Frame(f.name, f.gt_depth, FOCAL, BASELINE) for f in eigen]
    no_range = [Frame(f.name, f.gt_depth, FOCAL, BASELINE, crop=f.crop) for f in eigen]
    values = [
        evaluate_full(depth_maps(disps, frames), frames, EvalConfig())[0]["cap50"]["abs_rel"]
        for frames in (eigen, plain, no_range)
    ]
    assert len({round(v, 6) for v in values}) == 3


# ------------------------------------------------------------------ GT readers and the indexes


def test_gt_readers_give_depth_in_metres(tmp_path: Path) -> None:
    depth = np.zeros((6, 8), np.float32)
    depth[2:4, 3:6] = 12.5
    disp = np.where(depth > 0, FOCAL * BASELINE / np.where(depth > 0, depth, 1), 0)
    kitti.write_disparity(tmp_path / "disp.png", disp)
    got = read_gt_depth("disparity", tmp_path / "disp.png", focal=FOCAL, baseline=BASELINE)
    np.testing.assert_allclose(got, depth, rtol=2e-3)  # 1/256 px of disparity
    assert (got > 0).sum() == 6
    write_png(tmp_path / "depth.png", np.round(depth * 256).astype(np.uint16))
    np.testing.assert_array_equal(
        read_gt_depth("depth", tmp_path / "depth.png", focal=FOCAL, baseline=BASELINE), depth
    )
    day = tmp_path / "2011_09_26"
    _write_raw_calib(day)
    scan = tmp_path / "scan.bin"
    _random_cloud(2, 2000).tofile(scan)
    np.testing.assert_array_equal(
        read_gt_depth("velodyne", scan, calib=day, focal=FOCAL, baseline=BASELINE),
        kitti.velodyne_depth(scan, kitti.read_raw_calib(day)),
    )
    with pytest.raises(DataError, match="raw day folder"):
        read_gt_depth("velodyne", scan, focal=FOCAL, baseline=BASELINE)
    with pytest.raises(DataError, match="unknown GT kind 'lidar'"):
        read_gt_depth("lidar", scan, focal=FOCAL, baseline=BASELINE)


def _raw_drive(root: Path, frames: int, size=(375, 1242), scans: bool = True) -> tuple[Path, list[str]]:
    """A one-drive raw tree with the 2011_09_26 calibration (plus camera 3) and random scans."""
    day = root / "raw" / "2011_09_26"
    p3 = P2.copy()
    p3[0, 3] -= FOCAL * BASELINE
    _write_raw_calib(day, cam_extra="P_rect_03: " + " ".join(f"{v:.12e}" for v in p3.ravel()) + "\n")
    drive = day / "2011_09_26_drive_0002_sync"
    lines = []
    for i in range(frames):
        name = f"{i:010d}"
        for cam in ("image_02", "image_03"):
            write_png(drive / cam / "data" / f"{name}.png", np.full((*size, 3), 40 * i, np.uint8))
        if scans:
            (drive / "velodyne_points" / "data").mkdir(parents=True, exist_ok=True)
            _random_cloud(i, 3000).tofile(drive / "velodyne_points" / "data" / f"{name}.bin")
        rel = "2011_09_26/2011_09_26_drive_0002_sync"
        lines.append(f"{rel}/image_02/data/{name}.jpg {rel}/image_03/data/{name}.jpg")
    split = root / "eigen_test_files.txt"
    split.write_text("\n".join(lines) + "\n")
    return split, lines


def test_eigen_index_reads_back_as_frames_with_lidar_gt(tmp_path: Path) -> None:
    split, _ = _raw_drive(tmp_path, 2)
    index = eval_sets._build_eigen_index(tmp_path / "raw", split)
    assert list(index["frame"]) == [
        "2011_09_26_drive_0002_sync_0000000000",
        "2011_09_26_drive_0002_sync_0000000001",
    ]
    assert set(index["gt_kind"]) == {"velodyne"} and set(index["crop"]) == {"garg"}
    assert index["focal"].iloc[0] == pytest.approx(FOCAL) and index["baseline"].iloc[0] == pytest.approx(
        BASELINE
    )
    frames = load_frames(index)
    calib = kitti.read_raw_calib(tmp_path / "raw" / "2011_09_26")
    np.testing.assert_array_equal(frames[1].gt_depth, kitti.velodyne_depth(index["gt"].iloc[1], calib))
    assert frames[0].gt_in_range and frames[0].crop is not None
    assert not frames[0].valid[: int(0.40810811 * 375)].any()  # nothing above the crop counts


def test_eigen_index_names_what_is_missing(tmp_path: Path) -> None:
    split, _ = _raw_drive(tmp_path, 2, scans=False)
    with pytest.raises(DataError, match=r"2 of 2 frame\(s\) lack images or a velodyne_points scan"):
        eval_sets._build_eigen_index(tmp_path / "raw", split)


def test_eigen_benchmark_index_reads_the_annotated_depth(tmp_path: Path) -> None:
    _raw_drive(tmp_path, 2, scans=False)
    annotated = tmp_path / "depth_annotated"
    gt = np.zeros((375, 1242), np.uint16)
    gt[200:300, 100:900] = 20 * 256
    target = annotated / "val" / "2011_09_26_drive_0002_sync" / "proj_depth" / "groundtruth" / "image_02"
    for i in range(2):
        write_png(target / f"{i:010d}.png", gt)
    split = tmp_path / "bench.txt"
    split.write_text("2011_09_26/2011_09_26_drive_0002_sync 0 l\n2011_09_26/2011_09_26_drive_0002_sync 1 l\n")
    index = eval_sets._build_eigen_benchmark_index(tmp_path / "raw", split, annotated)
    frames = load_frames(index)
    assert set(index["gt_kind"]) == {"depth"}
    np.testing.assert_array_equal(frames[0].gt_depth, gt / 256.0)
    split.write_text("2011_09_26/2011_09_26_drive_0002_sync 7 l\n")
    with pytest.raises(DataError, match="lack raw images"):
        eval_sets._build_eigen_benchmark_index(tmp_path / "raw", split, annotated)
    split.write_text("2011_09_26/2011_09_26_drive_0002_sync seven l\n")
    with pytest.raises(DataError, match=r"bench.txt:1: expected"):
        eval_sets._build_eigen_benchmark_index(tmp_path / "raw", split, annotated)


def test_extra_sets_config() -> None:
    assert params_from_dict({"eval": {"extra_sets": []}}).eval.extra_sets == ()
    assert params_from_dict({}).eval.extra_sets == ("eigen",)
    with pytest.raises(ConfigError, match=r"eval.extra_sets\[0\]: 'kitti2016' is not one of"):
        params_from_dict({"eval": {"extra_sets": ["kitti2016"]}})
    with pytest.raises(ConfigError, match="eval.extra_sets: must not repeat a set"):
        params_from_dict({"eval": {"extra_sets": ["eigen", "eigen"]}})


def test_compare_section_of_an_extra_set(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The set's tables: one per cap, best variant in bold, differences to the reference with
    intervals, mean ± sd over seeds; metrics written by the suite and read back from disk."""
    import pandas as pd

    from msdepth.analysis.runs import group_metrics, paired_statistics, seed_spread
    from msdepth.config.params import CompareConfig
    from msdepth.evaluation.results import _write_suite, load_suite_metrics, load_unit_tables
    from msdepth.reporting.comparison import build_set_section

    monkeypatch.chdir(tmp_path)
    gts, disps = _sparse_scene(2, n=4, shape=(60, 200))
    frames = _eigen_frames(gts)
    groups = {
        "ssim": ["ssim/seed0", "ssim/seed1", "ssim/seed2"],
        "msssim": ["msssim/seed0", "msssim/seed1", "msssim/seed2"],
        "prior": ["prior"],
    }
    rng = np.random.default_rng(5)
    for run in (r for runs in groups.values() for r in runs):
        scale = 1.0 if run.startswith("msssim") else 1.3  # msssim closer to the truth
        pred = {
            f.name: np.where(f.gt_depth > 0, f.gt_depth * scale * rng.uniform(0.95, 1.05), 20.0)
            for f in frames
        }
        summary, table = evaluate_full(pred, frames, EvalConfig())
        _write_suite("full", run, summary, table, root=tmp_path / "sets", headline_root=tmp_path / "x")
    runs = [r for rs in groups.values() for r in rs]
    suites = load_suite_metrics(tmp_path / "sets", runs, ["full"])
    tables = load_unit_tables(tmp_path / "sets", runs, ["full"])
    assert isinstance(tables["full"]["prior"], pd.DataFrame)
    stats = paired_statistics(tables, groups, CompareConfig(bootstrap_samples=200), (80.0, 50.0))
    result, md = build_set_section(
        "eigen", group_metrics(suites, groups), ["ssim", "msssim"], ["prior"], stats,
        seed_spread(suites, groups, ["cap80", "cap50"]), (0, 1, 2),
    )  # fmt: skip
    assert md.startswith("# Eigen split (raw LiDAR GT, Garg crop)")
    assert "4 images" in md and "no median scaling" in md
    assert "## eigen: full image, cap 80 m" in md and "## eigen: full image, cap 50 m" in md
    row = next(line for line in md.splitlines() if line.startswith("| msssim | **"))
    assert float(row.split("**")[1]) == pytest.approx(result["full"]["cap80"]["msssim"]["abs_rel"], abs=5e-5)
    diff = next(line for line in md.splitlines() if line.startswith("| msssim | -"))
    assert diff.split("|")[2].strip().endswith("*")  # 3 seeds each, far apart: marked
    assert "Seed-to-seed spread (mean ± sd over 3 seeds" in md
    assert (tmp_path / "sets" / "full" / "prior.csv").is_file()
    assert (tmp_path / "x" / "full" / "prior.json").is_file()


def test_a_set_stage_for_an_unconfigured_set_names_the_configured_ones() -> None:
    from msdepth.pipeline.paths import checked_set

    params = params_from_dict({"eval": {"extra_sets": ["eigen"]}})
    assert checked_set(params, "eigen") == "eigen"
    with pytest.raises(ConfigError, match=r"'eigen_benchmark' is not in eval.extra_sets \['eigen'\]"):
        checked_set(params, "eigen_benchmark")
