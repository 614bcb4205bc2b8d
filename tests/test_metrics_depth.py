"""Metrics against hand-computed values and an independent reimplementation; depth conversion."""

import numpy as np
import pytest

from msdepth.config.params import params_from_dict
from msdepth.evaluation.metrics import METRICS, STEREO_METRICS, compute_errors
from msdepth.evaluation.suites import Frame, depth_maps, evaluate_full
from msdepth.geometry.depth import (
    clamp_depth,
    depth_to_disparity,
    disparity_to_depth,
    pixel_disparity,
    predicted_depth,
)


def test_compute_errors_hand_computed():
    gt = np.array([10.0, 20.0])
    pred = np.array([12.5, 20.0])
    m = compute_errors(gt, pred)
    # |10-12.5|/10 = 0.25, 0 -> mean 0.125; (2.5^2)/10 = 0.625 -> 0.3125
    assert m["abs_rel"] == pytest.approx(0.125)
    assert m["sq_rel"] == pytest.approx(0.3125)
    assert m["rmse"] == pytest.approx(np.sqrt(6.25 / 2))
    assert m["rmse_log"] == pytest.approx(np.sqrt(np.log(1.25) ** 2 / 2))
    # ratio 1.25 is not < 1.25: a1 = 0.5, but < 1.25^2: a2 = a3 = 1
    assert (m["a1"], m["a2"], m["a3"]) == (0.5, 1.0, 1.0)
    assert list(m) == list(METRICS)


def test_compute_errors_perfect_prediction():
    gt = np.linspace(1, 80, 100)
    m = compute_errors(gt, gt.copy())
    assert m["abs_rel"] == m["sq_rel"] == m["rmse"] == m["rmse_log"] == 0.0
    assert m["a1"] == m["a2"] == m["a3"] == 1.0


def test_compute_errors_matches_reference_formulas():
    rng = np.random.default_rng(0)
    gt = rng.uniform(1, 80, 1000).astype(np.float32)
    pred = (gt * rng.uniform(0.5, 1.6, 1000)).astype(np.float32)
    m = compute_errors(gt, pred)
    ratio = np.maximum(gt / pred, pred / gt)
    ref = {
        "abs_rel": np.mean(np.abs(gt - pred) / gt),
        "sq_rel": np.mean((gt - pred) ** 2 / gt),
        "rmse": np.sqrt(np.mean((gt - pred) ** 2)),
        "rmse_log": np.sqrt(np.mean((np.log(gt) - np.log(pred)) ** 2)),
        "a1": np.mean(ratio < 1.25),
        "a2": np.mean(ratio < 1.25**2),
        "a3": np.mean(ratio < 1.25**3),
    }
    for k, v in ref.items():
        assert m[k] == pytest.approx(float(v), rel=1e-6)


def test_compute_errors_rejects_bad_input():
    with pytest.raises(ValueError):
        compute_errors(np.array([]), np.array([]))
    with pytest.raises(ValueError):
        compute_errors(np.ones(3), np.ones(4))


def test_disparity_to_depth_kitti():
    disp = np.array([[0.0, 38.96, 721.5377 * 0.54]], np.float32)
    depth = disparity_to_depth(disp, 721.5377, 0.54)
    assert depth[0, 0] == 0.0  # invalid stays invalid
    assert depth[0, 1] == pytest.approx(721.5377 * 0.54 / 38.96, rel=1e-6)
    assert depth[0, 2] == pytest.approx(1.0, rel=1e-6)


def test_pixel_disparity_scales_by_gt_width():
    frac = np.full((8, 24), 0.1, np.float32)
    px = pixel_disparity(frac, 375, 1242)
    assert px.shape == (375, 1242)
    np.testing.assert_allclose(px, 124.2, rtol=1e-6)


def test_clamp_depth():
    d = np.array([0.0, 5.0, 100.0])
    np.testing.assert_array_equal(clamp_depth(d, 1e-3, 80.0), [1e-3, 5.0, 80.0])
    assert d[2] == 100.0  # input untouched


def test_predicted_depth_reads_a_zero_disparity_as_infinitely_far():
    """Monodepth's convention (f·B/d, no guard): a prediction's d <= 0 is infinite depth, which the
    cap then clamps to the farthest; GT's 0 stays "no GT" (disparity_to_depth)."""
    depth = predicted_depth(np.array([[10.0, 0.0, -1.0]]), 10.0, 1.0)
    assert depth.tolist() == [[1.0, np.inf, np.inf]] and depth.dtype == np.float32
    assert clamp_depth(depth, 1e-3, 80.0).tolist() == [[1.0, 80.0, 80.0]]
    assert depth_to_disparity(np.array([0.5, 0.0, np.inf]), 10.0, 1.0).tolist() == [20.0, 0.0, 0.0]


def test_the_full_suite_s_d1_and_epe_counted_by_hand():
    """A 2 x 3 frame, f·B = 10 px·m. GT disparity [[10, 20, 0], [40, 5, 50]] px (0: no GT),
    predicted [[10, 24, 7], [40, 9, 0]] px. Off: 0, 4, –, 0, 4 and, at cap 80 m, 50 − 10/80 =
    49.875 px (0 px is infinitely far, clamped to the cap). Outliers (> 3 px and > 5 %): 20→24,
    5→9 and 50→0.125: D1 3/5; EPE 57.875/5. At cap 50 m the last is 49.8 px off: EPE 57.8/5. The
    same GT given as depth (LiDAR's form) gives the same numbers: GT disparity is f·B/depth."""
    gt = np.array([[10, 20, 0], [40, 5, 50]], dtype=np.float32)
    pred_px = np.array([[10, 24, 7], [40, 9, 0]], dtype=np.float32)
    cfg = params_from_dict({"eval": {"caps": [80, 50]}}).eval
    by_disparity = Frame.from_disparity("a", gt, 10.0, 1.0)
    by_depth = Frame("a", disparity_to_depth(gt, 10.0, 1.0), 10.0, 1.0)
    for frame in (by_disparity, by_depth):
        pred = depth_maps(pred_px[None] / 3, [frame])  # fractions of the width, as the infer stage's
        assert pred["a"][1, 2] == np.inf
        summary, table = evaluate_full(pred, [frame], cfg)
        assert summary["cap80"]["d1"] == pytest.approx(3 / 5)
        assert summary["cap80"]["epe"] == pytest.approx(57.875 / 5, rel=1e-6)
        assert summary["cap50"]["d1"] == pytest.approx(3 / 5)
        assert summary["cap50"]["epe"] == pytest.approx(57.8 / 5, rel=1e-6)
        assert list(table.columns[-2:]) == list(STEREO_METRICS)
