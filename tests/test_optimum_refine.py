"""The optimum's matched starts (msdepth.optimum.starts) and its refinement from them
(msdepth.optimum.solver.optimise with ``start``), on known answers at tiny sizes, and on a real KITTI
2015 frame at a small working size when ../shared/real-samples is there."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch
from test_optimum import SHIFT, H, W, plane_pair, small

from msdepth.__main__ import main
from msdepth.config.params import Params, params_from_dict
from msdepth.data.kitti import read_disparity, read_image
from msdepth.data.pairs import resize, to_tensor
from msdepth.errors import ConfigError
from msdepth.evaluation.metrics import stereo_errors
from msdepth.io import write_png
from msdepth.optimum.solver import _start_logits, objective, optimise, optimum_disparities, working_weight
from msdepth.optimum.starts import _right_from_left, capped_size, start_disparity

KITTI2015 = Path(__file__).resolve().parents[2] / "shared" / "real-samples" / "kitti2015-training"
TRUTH = SHIFT / W  # the plane's disparity as a fraction of the width
INTERIOR = (slice(4, -4), slice(SHIFT + 4, -4))  # columns left of the shift see nothing of theirs


def refine(variant: str, start: float) -> np.ndarray:
    """The plane pair's left optimum (px) refined from a constant ``start`` (px) in both views."""
    params = Params()
    left, right = (to_tensor(x)[None] for x in plane_pair())
    init = torch.full((1, 2, H, W), start / W)
    disp = optimise(left, right, objective(params, variant), params.optimum, start=init)
    return disp[0, 0].numpy() * W


@pytest.mark.parametrize("variant", ["ssim", "msssim"])
def test_refinement_from_the_truth_stays_there(variant: str) -> None:
    """Measured: median 0.03 px, mean 0.04 px off, both variants (the interior's max 0.2 px)."""
    error = np.abs(refine(variant, SHIFT)[INTERIOR] - SHIFT)
    assert np.median(error) < 0.1 and error.mean() < 0.1, (np.median(error), error.mean())


@pytest.mark.parametrize("variant", ["ssim", "msssim"])
@pytest.mark.parametrize("offset", [3, -3])
def test_refinement_from_a_start_a_few_pixels_off_reaches_the_truth(variant: str, offset: int) -> None:
    """From 3 px nearer or farther: measured median 0.03 px, mean 0.04 px off (max 0.24 px)."""
    error = np.abs(refine(variant, SHIFT + offset)[INTERIOR] - SHIFT)
    assert np.median(error) < 0.1 and error.mean() < 0.2, (np.median(error), error.mean())


def test_refinement_runs_the_refine_settings_at_the_finest_levels() -> None:
    left, right = (to_tensor(x)[None] for x in plane_pair())
    params = small(Params(), refine_levels=2, refine_iterations=4, levels=3, iterations=9)
    trace: list[list[float]] = []
    optimise(left, right, objective(params, "ssim"), params.optimum, trace, torch.full((1, 2, H, W), TRUTH))
    assert [len(t) for t in trace] == [4, 4]  # 48 x 160: levels of 24 and 48 rows
    with pytest.raises(ValueError, match="start of shape"):
        optimise(left, right, objective(params, "ssim"), params.optimum, start=torch.zeros(1, 1, H, W))


def test_start_logits_keep_the_range_s_ends_off() -> None:
    disp = 0.3 * torch.sigmoid(_start_logits(torch.tensor([0.0, 0.075, 0.3, 0.5])))
    assert disp[0] > 0 and disp[2] < 0.3 and disp[3] == disp[2]
    assert disp[1] == pytest.approx(0.075, rel=1e-5)


def test_the_cost_start_is_the_default() -> None:
    """optimum.start defaults to cost (SGM on the variant's own cost volume, the best by measurement:
    docs/optimum.md); the constant start stays one key away."""
    defaults = Params()
    assert (defaults.optimum.start, defaults.optimum.smoothness_width) == ("cost", 414)
    params = small(defaults, refine_levels=1, refine_iterations=3, start=defaults.optimum.start)
    pair = [plane_pair()]
    default = optimum_disparities(pair, params, "ssim", progress=False)[0]
    cost = optimum_disparities(pair, params, "ssim", progress=False, start="cost")[0]
    assert default.tobytes() == cost.tobytes()
    assert np.median(np.abs(default[INTERIOR] * W - SHIFT)) < 0.5


# ----------------------------------------------------------------------------- the starts


def test_right_from_left_warps_with_occlusion() -> None:
    """A foreground at 3 px (x = 4..6) over a background at 0: the right view sees it at x = 1..3,
    and the background it uncovers (x = 4..6) takes the lower neighbour, the background."""
    left = np.array([[0, 0, 0, 0, 3, 3, 3, 0, 0, 0]], dtype=np.float32)
    assert _right_from_left(left).tolist() == [[0, 3, 3, 3, 0, 0, 0, 0, 0, 0]]
    plane = np.full((4, 20), 2.5, dtype=np.float32)
    np.testing.assert_array_equal(_right_from_left(plane), plane)  # the right edge: its lower neighbour


@pytest.mark.parametrize("start", ["cost", "sgbm"])
def test_a_matched_start_has_both_views_at_any_size(start: str) -> None:
    left, right = plane_pair()
    full = start_disparity(left, right, Params(), "ssim", start)
    assert full.shape == (2, H, W) and full.dtype == np.float32
    assert full.min() >= 0 and full.max() <= 0.3
    for view in full:  # both views: the plane's disparity
        assert np.median(np.abs(view[INTERIOR] - TRUTH)) * W < 0.5
    half = start_disparity(left, right, Params(), "ssim", start, (24, 80))
    assert half.shape == (2, 24, 80)
    assert np.median(np.abs(half[0, 2:-2, SHIFT // 2 + 2 : -2] - TRUTH)) * W < 0.5  # a fraction of width


def test_the_constant_start_and_bad_starts() -> None:
    left, right = plane_pair()
    constant = start_disparity(left, right, Params(), "ssim", "constant", (24, 80))
    assert constant.shape == (2, 24, 80) and np.all(constant == Params().optimum.init_disparity)
    with pytest.raises(ConfigError, match="unknown start 'nope'"):
        start_disparity(left, right, Params(), "ssim", "nope")
    with pytest.raises(ConfigError, match="no per-pixel form"):
        start_disparity(left, right, Params(), "mix", "cost")


def test_optimum_disparities_refines_a_batch_from_matched_starts() -> None:
    params = small(Params(), batch_size=2, refine_iterations=10)
    pairs = [plane_pair(), plane_pair(8)]
    first, second = optimum_disparities(pairs, params, "ssim", progress=False, start="sgbm")
    assert np.median(np.abs(first[INTERIOR] * W - SHIFT)) < 0.5
    assert np.median(np.abs(second[INTERIOR] * W - 8)) < 0.5


# ----------------------------------------------------------------------------- the width cap


def test_capped_size_halves_while_wider_than_the_cap() -> None:
    assert capped_size((375, 1242), 640) == (187, 621)  # KITTI: half size, rounding down
    assert capped_size((375, 1242), 320) == (93, 310)
    assert capped_size((125, 414), 640) == (125, 414)  # the render size: as it is
    assert capped_size((375, 1242), 0) == (375, 1242)  # 0: no cap
    assert capped_size((50, 4000), 640) == (25, 2000)  # never a side under 24 px


def test_a_pair_wider_than_the_cap_is_solved_at_its_halving_and_resized_back() -> None:
    """Exactly the half-size pair's optimum, bilinear to the full size: the cap is one rule for the
    matcher and the solver, so full and half size give one answer (docs/optimum.md)."""
    left, right = plane_pair()
    half_pair = [(resize(left, H // 2, W // 2), resize(right, H // 2, W // 2))]
    params = small(Params(), start="cost", refine_levels=1, refine_iterations=3, smoothness_width=414)
    capped = dataclasses.replace(params, optimum=dataclasses.replace(params.optimum, max_width=W // 2))
    full = optimum_disparities([(left, right)], capped, "ssim", progress=False)[0]
    half = optimum_disparities(half_pair, params, "ssim", progress=False)[0]
    assert full.shape == (H, W) and half.shape == (H // 2, W // 2) and full.dtype == np.float32
    up = torch.nn.functional.interpolate(torch.from_numpy(half)[None, None], size=(H, W), mode="bilinear")
    np.testing.assert_array_equal(full, up[0, 0].numpy())
    uncapped = optimum_disparities([(left, right)], params, "ssim", progress=False)[0]
    assert not np.array_equal(full, uncapped)  # the default cap (640 px) leaves 160 px as it is
    start = start_disparity(left, right, capped, "ssim", "cost")
    np.testing.assert_array_equal(start, start_disparity(*half_pair[0], params, "ssim", "cost", (H, W)))


# ----------------------------------------------------------------------------- params and CLI


def test_the_start_and_refinement_keys_are_checked() -> None:
    assert Params().optimum.start == "cost"
    assert params_from_dict({"optimum": {"start": "constant"}}).optimum.start == "constant"
    with pytest.raises(ConfigError, match=r"optimum.start: 'nope' is not one of \['constant', 'cost', "):
        params_from_dict({"optimum": {"start": "nope"}})
    for key in ("refine_levels", "refine_iterations"):
        with pytest.raises(ConfigError, match=f"optimum.{key}"):
            params_from_dict({"optimum": {key: 0}})
    assert Params().optimum.max_width == 640
    assert params_from_dict({"optimum": {"max_width": 0}}).optimum.max_width == 0
    for bad in (-1, 32, 5000):
        with pytest.raises(ConfigError, match=r"optimum.max_width: must be 0 \(no cap\) or in 64..4096 px"):
            params_from_dict({"optimum": {"max_width": bad}})


def test_cli_start_flag(tmp_path, capsys) -> None:
    left, right = plane_pair()
    write_png(tmp_path / "l.png", left)
    write_png(tmp_path / "r.png", right)
    args = ["optimum", str(tmp_path / "l.png"), str(tmp_path / "r.png"), "--variant", "ssim", "--quiet"]
    fast = ["--set", "optimum.refine_iterations=5"]
    assert main([*args, "--out", str(tmp_path / "a"), "--start", "sgbm", *fast]) == 0
    disp = np.load(tmp_path / "a" / "l_ssim_disp.npy")
    assert disp.shape == (H, W) and np.median(np.abs(disp[INTERIOR] - SHIFT)) < 0.5
    assert main([*args, "--out", str(tmp_path / "b"), "--start", "nope"]) == 1
    assert "optimum.start: 'nope' is not one of ['constant', 'cost', 'sgbm']" in capsys.readouterr().err
    (tmp_path / "p.yaml").write_text("optimum:\n  start: sgbm\n  refine_iterations: 5\n")
    assert main([*args, "--out", str(tmp_path / "c"), "--params", str(tmp_path / "p.yaml")]) == 0
    np.testing.assert_array_equal(np.load(tmp_path / "c" / "l_ssim_disp.npy"), disp)  # the key is the flag


# ----------------------------------------------------------------------------- a real KITTI 2015 frame


def test_refinement_from_sgbm_on_real_kitti_2015_at_quarter_size() -> None:
    """000001_10 refined at 93 x 310 from SGBM's start (matched at full size), scored at the GT's
    pixels of the quarter-size grid (GT sampled every 4th px, divided by 4: 3 px there are 12 at
    full size). Measured: D1 1.9 % at the start, 3.8 % refined (EPE 0.40 and 0.63 px); on
    000000_10, 2.4 % and 3.2 %."""
    if not KITTI2015.is_dir():
        pytest.skip("../shared/real-samples is not available")
    left, right = (read_image(KITTI2015 / d / "000001_10.png") for d in ("image_2", "image_3"))
    gt = read_disparity(KITTI2015 / "disp_occ_0" / "000001_10.png")
    size = (gt.shape[0] // 4, gt.shape[1] // 4)
    init = start_disparity(left, right, Params(), "ssim", "sgbm", size)
    pair = [to_tensor(resize(x, *size))[None] for x in (left, right)]
    disp = optimise(*pair, objective(Params(), "ssim"), Params().optimum, start=torch.from_numpy(init)[None])
    gt_small = gt[: 4 * size[0] : 4, : 4 * size[1] : 4] / 4
    start = stereo_errors(gt_small, init[0] * size[1])
    refined = stereo_errors(gt_small, disp[0, 0].numpy() * size[1])
    assert start["d1"] < 0.04 and refined["d1"] < 0.07 and refined["epe"] < 1.0, (start, refined)


def test_the_smoothness_weight_scales_with_the_working_width_when_asked() -> None:
    params = small(Params())  # smoothness_width 0: not scaled
    assert working_weight(params, 1242) == params.optimum.smoothness_weight
    scaled = Params()  # the default: the weights hold at 414 px, the render width
    assert working_weight(scaled, 414) == scaled.optimum.smoothness_weight
    assert working_weight(scaled, 1242) == pytest.approx(30.0) and working_weight(scaled, 207, 3.0) == 1.5
    with pytest.raises(ConfigError, match="optimum.smoothness_width"):
        params_from_dict({"optimum": {"smoothness_width": -1}})
    # At twice the reference width, the optimum is the unscaled one's at twice the weight.
    fast = small(params, levels=1, iterations=5)
    pair = [plane_pair()]
    doubled = optimum_disparities(pair, small(fast, smoothness_width=W // 2), "ssim", progress=False)[0]
    twice = optimum_disparities(pair, fast, "ssim", 2 * fast.optimum.smoothness_weight, progress=False)[0]
    assert doubled.tobytes() == twice.tobytes()
