"""The evaluation suites against an independent reimplementation of Monodepth's evaluation."""

import cv2
import numpy as np
import pandas as pd
import pytest

from msdepth.analysis.comparison import comparison_data
from msdepth.config.params import EvalConfig
from msdepth.evaluation.suites import Frame, depth_maps, evaluate_full, evaluate_gradients, evaluate_roi
from msdepth.reporting.comparison import build_comparison

FOCAL, BASELINE = 721.5377, 0.54


def monodepth_kitti2015(pred_disparities, gt_disparities, cap, min_depth=1e-3):
    """Straight transcription of Monodepth's evaluate_kitti.py (split kitti, no GT masking)."""
    results = []
    for pred_disp, gt_disp in zip(pred_disparities, gt_disparities, strict=True):
        height, width = gt_disp.shape
        pred_disp = width * cv2.resize(pred_disp, (width, height), interpolation=cv2.INTER_LINEAR)
        mask = gt_disp > 0
        gt_depth = FOCAL * BASELINE / (gt_disp + (1.0 - mask))
        pred_depth = FOCAL * BASELINE / (pred_disp + (1.0 - mask))
        pred_depth[pred_depth < min_depth] = min_depth
        pred_depth[pred_depth > cap] = cap
        gt, pred = gt_depth[mask], pred_depth[mask]
        thresh = np.maximum((gt / pred), (pred / gt))
        results.append(
            [
                np.mean(np.abs(gt - pred) / gt),
                np.mean(((gt - pred) ** 2) / gt),
                np.sqrt(((gt - pred) ** 2).mean()),
                np.sqrt(((np.log(gt) - np.log(pred)) ** 2).mean()),
                (thresh < 1.25).mean(),
                (thresh < 1.25**2).mean(),
                (thresh < 1.25**3).mean(),
            ]
        )
    return np.mean(results, axis=0)


def _disparity(frame: Frame) -> np.ndarray:
    """The GT disparity a frame's depth came from (the Monodepth transcription takes disparities)."""
    valid = frame.gt_depth > 0
    return np.where(valid, FOCAL * BASELINE / np.where(valid, frame.gt_depth, 1.0), 0.0)


@pytest.fixture
def scene():
    rng = np.random.default_rng(3)
    frames, preds = [], []
    for i in range(3):
        gt = rng.uniform(2, 120, (375, 1242)).astype(np.float32)
        gt[rng.random(gt.shape) < 0.6] = 0  # sparse, like KITTI
        frames.append(Frame.from_disparity(f"{i:06d}_10", gt, FOCAL, BASELINE))
        preds.append(rng.uniform(0.002, 0.25, (64, 192)).astype(np.float32))
    return frames, np.stack(preds)


def test_full_suite_matches_monodepth(scene):
    frames, disps = scene
    cfg = EvalConfig()
    summary, table = evaluate_full(depth_maps(disps, frames), frames, cfg)
    for cap in cfg.caps:
        ref = monodepth_kitti2015(disps, [_disparity(f) for f in frames], cap)
        ours = [
            summary[f"cap{cap:g}"][k] for k in ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")
        ]
        np.testing.assert_allclose(ours, ref, rtol=1e-6, atol=1e-6)
    assert len(table) == len(frames) * len(cfg.caps)


def test_all_invalid_frame_is_excluded_and_counted(scene):
    frames, disps = scene
    frames[1] = Frame.from_disparity(frames[1].name, np.zeros_like(frames[1].gt_depth), FOCAL, BASELINE)
    summary, _ = evaluate_full(depth_maps(disps, frames), frames, EvalConfig())
    assert summary["excluded_images"] == 1
    ref = monodepth_kitti2015(disps[[0, 2]], [_disparity(frames[0]), _disparity(frames[2])], 80)
    assert summary["cap80"]["abs_rel"] == pytest.approx(ref[0], rel=1e-6)


def test_gt_masking_beyond_cap_is_a_param(scene):
    frames, disps = scene
    pred = depth_maps(disps, frames)
    plain, _ = evaluate_full(pred, frames, EvalConfig())
    masked, _ = evaluate_full(pred, frames, EvalConfig(mask_gt_beyond_cap=True))
    assert plain["cap50"]["abs_rel"] != masked["cap50"]["abs_rel"]


def _dense_frame(depth: np.ndarray, name="000000_10") -> Frame:
    return Frame.from_disparity(name, (FOCAL * BASELINE / depth).astype(np.float32), FOCAL, BASELINE)


def test_roi_suite_per_class_and_perfect_prediction():
    depth = np.full((60, 80), 20.0, np.float32)
    depth[10:30, 10:40] = 8.0
    frame = _dense_frame(depth)
    pred = {frame.name: depth.copy()}
    pred[frame.name][40:60, 50:80] *= 1.5  # a wrong region
    rois = pd.DataFrame(
        [(frame.name, "car", 10, 10, 40, 30), (frame.name, "sign", 50, 40, 80, 60)],
        columns=["image", "class", "x0", "y0", "x1", "y1"],
    )
    summary, table = evaluate_roi(pred, [frame], rois, EvalConfig())
    by_class = summary["cap80"]["by_class"]
    assert by_class["car"]["abs_rel"] == pytest.approx(0.0, abs=1e-5)
    assert by_class["sign"]["abs_rel"] == pytest.approx(0.5, rel=1e-4)
    assert summary["cap80"]["overall"]["abs_rel"] == pytest.approx(0.25, rel=1e-4)
    assert summary["cap80"]["overall"]["count"] == 2


def test_gradient_suite_on_a_ramp():
    # Depth rising 0.1 m per column: Sobel x = 8 * 0.1 in the interior, Sobel y and Laplacian 0.
    depth = np.tile(10 + 0.1 * np.arange(80, dtype=np.float32), (60, 1))
    frame = _dense_frame(depth)
    rois = pd.DataFrame(
        [(frame.name, "glass", 20, 20, 60, 40)], columns=["image", "class", "x0", "y0", "x1", "y1"]
    )
    summary, _ = evaluate_gradients({frame.name: depth}, [frame], rois, EvalConfig())
    block = summary["cap80"]
    assert block["overall"]["pred_sobel_x"] == pytest.approx(0.8, rel=1e-3)
    assert block["overall"]["pred_sobel_y"] == pytest.approx(0.0, abs=1e-4)
    assert block["overall"]["pred_laplacian"] == pytest.approx(0.0, abs=1e-3)
    dense = block["dense_gt"]["overall"]
    assert dense["gt_sobel_x"] == pytest.approx(0.8, rel=1e-3)
    assert dense["error_sobel_x"] == pytest.approx(0.0, abs=1e-3)


def test_compare_table_marks_best_variant():
    def suite(v):
        return {
            "cap80": {
                "abs_rel": v,
                "sq_rel": v,
                "rmse": v,
                "rmse_log": v,
                "a1": 1 - v,
                "a2": 1 - v,
                "a3": 1 - v,
            }
        }

    def roi(v):
        m = suite(v)["cap80"]
        return {"cap80": {"overall": {**m, "count": 1}, "by_class": {"car": {**m, "count": 1}}}}

    def grad(v):
        g = {"pred_sobel_x": v, "pred_sobel_y": v, "pred_laplacian": v, "count": 1}
        return {
            "cap80": {"overall": g, "by_class": {}, "dense_gt": {"overall": {"count": 0}, "by_class": {}}}
        }

    runs = {"ssim": 0.3, "msssim": 0.2, "prior": 0.1}
    suites = {
        "full": {r: suite(v) for r, v in runs.items()},
        "roi": {r: roi(v) for r, v in runs.items()},
        "gradients": {r: grad(v) for r, v in runs.items()},
    }
    result, md = build_comparison(comparison_data(suites, ["ssim", "msssim"], ["prior"]))
    assert "| msssim | **0.2000** |" in md  # best variant in bold; baselines never are
    assert result["full"]["cap80"]["prior"]["abs_rel"] == 0.1


def _frames_with_depth(depths):
    return [
        Frame(f"{i:06d}_10", np.where(d > 0, d, 0).astype(np.float32), FOCAL, BASELINE)
        for i, d in enumerate(depths)
    ]


def test_image_dependence_tells_a_prior_from_a_network_that_follows_the_scene():
    from msdepth.evaluation.suites import image_dependence

    rng = np.random.default_rng(0)
    depths = [rng.uniform(5, 60, (30, 90)).astype(np.float32) for _ in range(6)]
    depths[0][:5] = 0  # invalid GT somewhere
    frames = _frames_with_depth(depths)
    gt = {f.name: f.gt_depth for f in frames}
    exact = image_dependence(gt, frames, 80.0)
    assert exact["variation_ratio"] == pytest.approx(1.0, rel=1e-4)
    # A scale error does not change how much the prediction follows the scene.
    assert image_dependence({k: 1.3 * v for k, v in gt.items()}, frames, 80.0)[
        "variation_ratio"
    ] == pytest.approx(1.0, rel=1e-4)
    # The same map for every image (a prior, or a constant) does not depend on the image at all.
    prior = np.median(np.stack(depths), axis=0)
    assert image_dependence({k: prior for k in gt}, frames, 80.0)["variation_ratio"] == pytest.approx(
        0.0, abs=1e-9
    )
    half = {k: 0.5 * v + 0.5 * prior for k, v in gt.items()}
    assert 0.3 < image_dependence(half, frames, 80.0)["variation_ratio"] < 0.7
    # Frames of different sizes (KITTI's widths vary by day) share the smallest grid.
    mixed = _frames_with_depth(
        [depths[0], cv2.resize(depths[1], (92, 30), interpolation=cv2.INTER_NEAREST), *depths[2:]]
    )
    assert image_dependence({f.name: f.gt_depth for f in mixed}, mixed, 80.0)[
        "variation_ratio"
    ] == pytest.approx(1.0, rel=1e-4)


def test_full_suite_reports_image_dependence(scene):
    frames, preds = scene
    summary, _ = evaluate_full(depth_maps(preds, frames), frames, EvalConfig())
    assert set(summary["image_dependence"]) == {"pixels", "pred_variation", "gt_variation", "variation_ratio"}
    assert summary["image_dependence"]["variation_ratio"] > 0


def test_roi_suite_over_exact_masks_ignores_the_background_in_the_box():
    from msdepth.data.kitti import CLASS_BITS

    depth = np.full((20, 40), 30.0, np.float32)
    depth[5:15, 10:20] = 8.0  # a car in front of a wall at 30 m
    classes = np.zeros((20, 40), np.uint8)
    classes[5:15, 10:20] = CLASS_BITS["car"]
    disp = (FOCAL * BASELINE / depth).astype(np.float32)
    frame = Frame.from_disparity("000000_10", disp, FOCAL, BASELINE, class_map=classes)
    pred = np.where(classes > 0, 8.0, 12.0).astype(np.float32)  # right on the car, wrong on the wall
    rois = pd.DataFrame(
        [("000000_10", "car", 5, 2, 25, 18)], columns=["image", "class", "x0", "y0", "x1", "y1"]
    )
    summary, table = evaluate_roi({"000000_10": pred}, [frame], rois, EvalConfig(caps=(80.0,)))
    assert summary["cap80"]["overall"]["abs_rel"] > 0.2  # the box mixes in the wall
    assert summary["masks"]["cap80"]["overall"]["abs_rel"] == pytest.approx(0.0, abs=1e-6)
    assert summary["masks"]["cap80"]["by_class"]["car"]["count"] == 1 and summary["masks"]["rois"] == 1
    assert len(table) == 1  # the per-ROI table (and its bootstrap) stays the boxes'
    no_maps = Frame(frame.name, frame.gt_depth, FOCAL, BASELINE)
    assert "masks" not in evaluate_roi({"000000_10": pred}, [no_maps], rois, EvalConfig(caps=(80.0,)))[0]


def test_compare_shows_the_exact_mask_tables():
    metrics = {"abs_rel": 0.2, "sq_rel": 0.2, "rmse": 0.2, "rmse_log": 0.2, "a1": 0.8, "a2": 0.8, "a3": 0.8}

    def roi(v):
        m = {**metrics, "abs_rel": v, "count": 1}
        masks = {"cap80": {"overall": m, "by_class": {"car": m}}, "rois": 1, "excluded_rois": 0}
        return {"cap80": {"overall": m, "by_class": {"car": m}}, "masks": masks}

    grad = {
        "cap80": {
            "overall": {"pred_sobel_x": 1, "pred_sobel_y": 1, "pred_laplacian": 1},
            "dense_gt": {"overall": {}},
        }
    }
    runs = {"ssim": 0.3, "msssim": 0.1}
    suites = {
        "full": {r: {"cap80": metrics} for r in runs},
        "roi": {r: roi(v) for r, v in runs.items()},
        "gradients": {r: grad for r in runs},
    }
    result, md = build_comparison(comparison_data(suites, ["ssim", "msssim"], []))
    assert "### ROI, exact masks, cap 80 m" in md and "| msssim | 0.1000 | 0.2000 | 0.8000 | 0.1000 |" in md
    assert result["roi_masks"]["cap80"]["ssim"]["overall"]["abs_rel"] == 0.3


def test_compare_names_missing_baselines_with_their_reasons():
    metrics = {"abs_rel": 0.2, "sq_rel": 0.2, "rmse": 0.2, "rmse_log": 0.2, "a1": 0.8, "a2": 0.8, "a3": 0.8}
    roi = {"cap80": {"overall": {**metrics, "count": 1}, "by_class": {}}}
    grad = {
        "cap80": {
            "overall": {"pred_sobel_x": 1, "pred_sobel_y": 1, "pred_laplacian": 1},
            "dense_gt": {"overall": {}},
        }
    }
    suites = {
        "full": {r: {"cap80": metrics} for r in ("ssim", "constant")},
        "roi": {r: roi for r in ("ssim", "constant")},
        "gradients": {r: grad for r in ("ssim", "constant")},
    }
    missing = {"prior": "no metrics/full/prior.json"}
    result, md = build_comparison(comparison_data(suites, ["ssim"], ["constant"], missing_baselines=missing))
    assert "Missing baselines (not built): prior: no metrics/full/prior.json." in md
    assert result["missing_baselines"] == missing and result["baselines"] == ["constant"]
    two = {"constant": "no training GT", "prior": "no metrics/full/prior.json"}
    _, md = build_comparison(comparison_data(suites, ["ssim"], [], missing_baselines=two))
    assert "Missing baselines (not built): constant: no training GT; prior: no metrics/full/prior.json." in md
    _, md = build_comparison(comparison_data(suites, ["ssim"], ["constant"]))
    assert "Missing" not in md


def test_compare_says_when_image_dependence_cannot_be_measured():
    """One evaluation frame (or GT never at the same pixels in 3): the ratio is NaN, which must
    read as "not measured", not as "follows the image"."""
    from msdepth.analysis.runs import image_dependence as compare_dependence
    from msdepth.evaluation.suites import image_dependence

    frame = _frames_with_depth([np.full((10, 20), 20.0, dtype=np.float32)])
    measured = image_dependence({frame[0].name: frame[0].gt_depth}, frame, 80.0)
    assert np.isnan(measured["variation_ratio"])
    metrics = {"abs_rel": 0.2, "sq_rel": 0.2, "rmse": 0.2, "rmse_log": 0.2, "a1": 0.8, "a2": 0.8, "a3": 0.8}
    table = pd.DataFrame([{"frame": frame[0].name, "cap": 80.0, **metrics}])
    suites = {"full": {"ssim": {"cap80": metrics, "image_dependence": measured}}}
    dependence = compare_dependence(suites, {"full": {"ssim": table}}, {"ssim": ["ssim"]}, "prior", 80.0)
    assert dependence["ssim"] == {"variation_ratio": None, "prior_correlation": None, "image_blind": False}
    roi = {"cap80": {"overall": {**metrics, "count": 1}, "by_class": {}}}
    grad = {
        "cap80": {
            "overall": {"pred_sobel_x": 1, "pred_sobel_y": 1, "pred_laplacian": 1},
            "dense_gt": {"overall": {}},
        }
    }
    suites = {"full": suites["full"], "roi": {"ssim": roi}, "gradients": {"ssim": grad}}
    _, md = build_comparison(
        comparison_data(suites, ["ssim"], [], dependence=dependence, groups={"ssim": ["ssim"]})
    )
    assert "| ssim | – | – | not measured: too few evaluation frames with GT at the same pixels, " in md
