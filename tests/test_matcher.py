"""The loss's own cost volume (msdepth.optimum.cost_volume), semi-global matching on it
(msdepth.optimum.sgm), OpenCV's SGBM (msdepth.optimum.sgbm) and KITTI's D1, on known answers at
tiny sizes, and on two real KITTI 2015 frames when ../shared/real-samples is there."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from msdepth.config.params import Params
from msdepth.data.kitti import read_disparity, read_image
from msdepth.data.pairs import to_tensor
from msdepth.errors import ConfigError, DataError
from msdepth.evaluation.metrics import stereo_errors
from msdepth.losses.appearance import build_appearance
from msdepth.losses.monodepth import reconstruct
from msdepth.losses.ssim import ms_ssim
from msdepth.optimum import cost_volume as cv
from msdepth.optimum.sgbm import _num_disparities, sgbm_disparity
from msdepth.optimum.sgm import (
    SGMConfig,
    _aggregate,
    _lr_valid,
    _path_step,
    _right_disparity,
    _subpixel,
    fill_holes,
    sgm,
)

SHARED = Path(__file__).resolve().parents[2] / "shared"
KITTI2015 = SHARED / "real-samples" / "kitti2015-training"
H, W, D = 40, 128, 16  # tiny pairs; D: the largest disparity searched


def texture(height: int, width: int, seed: int = 0) -> np.ndarray:
    """A textured surface's float image in [0, 1] (H, W, 3): smooth blobs plus fine grain, band-limited
    (blurred), so that a sub-pixel shift by interpolation is a faithful one."""
    rng = np.random.default_rng(seed)
    coarse = cv2.resize(
        rng.random((height // 8, width // 8, 3)), (width, height), interpolation=cv2.INTER_CUBIC
    )
    fine = cv2.GaussianBlur(rng.random((height, width, 3)), (0, 0), 1.0)
    return np.clip(0.5 * coarse + 1.2 * (fine - 0.5) + 0.25, 0, 1)


def sample(image: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """``image`` (H, W', 3) read at float ``columns`` (H, W) by cubic interpolation."""
    rows = np.broadcast_to(np.arange(columns.shape[0], dtype=np.float32)[:, None], columns.shape)
    return cv2.remap(
        image.astype(np.float32), columns.astype(np.float32), np.ascontiguousarray(rows), cv2.INTER_CUBIC
    )


def scene(fore: float, back: float, box: tuple[int, int, int, int] | None = None) -> tuple[np.ndarray, ...]:
    """A stereo pair (H, W, 3 floats) of a background plane at disparity ``back`` and, in ``box``
    (x0, y0, x1, y1 of the left view), a fronto-parallel foreground plane at ``fore``, rendered with
    occlusion; and the left view's true disparity. Left pixel x of a plane at d is right pixel x - d."""
    margin = 2 * D
    background, foreground = texture(H, W + 2 * margin, 1), texture(H, W + 2 * margin, 2)
    x = np.broadcast_to(np.arange(W, dtype=np.float64)[None], (H, W))
    in_box = np.zeros((H, W), dtype=bool)
    x0, y0, x1, y1 = box or (0, 0, 0, 0)
    in_box[y0:y1, x0:x1] = True
    left = np.where(in_box[..., None], sample(foreground, x + margin), sample(background, x + margin))
    # The right view: the foreground where a box pixel lands, the background elsewhere.
    seen = np.zeros((H, W), dtype=bool)
    seen[y0:y1] = (((x + fore) >= x0) & ((x + fore) < x1))[y0:y1]
    right = np.where(
        seen[..., None], sample(foreground, x + fore + margin), sample(background, x + back + margin)
    )
    return left, right, np.where(in_box, fore, back)


def tensors(*images: np.ndarray) -> list[torch.Tensor]:
    return [torch.from_numpy(np.ascontiguousarray(i.transpose(2, 0, 1))).float() for i in images]


def params_with(**sections) -> Params:
    params = Params()
    appearance = {**params.appearance}
    for name, changes in sections.items():
        appearance[name] = dataclasses.replace(appearance[name], **changes)
    return dataclasses.replace(params, appearance=appearance)


COSTS = {
    "ssim": cv.matching_cost(Params(), "ssim"),
    "msssim": cv.matching_cost(Params(), "msssim"),
    "msssim_k7": cv.matching_cost(params_with(msssim={"kernel_size": 7}), "msssim"),
}


# ----------------------------------------------------------------------------- the cost


def test_matching_cost_reads_the_variants_sections():
    params = Params()
    assert cv.matching_cost(params, "ssim") == cv.MatchingCost(params.loss.alpha, 3)
    msssim = cv.matching_cost(params, "msssim")
    assert msssim.levels == 4 and msssim.kernel_size == 3
    assert sum(msssim.weights) == pytest.approx(1.0) and msssim.weights[0] < msssim.weights[1]
    learned = cv.matching_cost(params_with(msssim={"weights": "learned"}), "msssim")
    assert learned.weights == pytest.approx((0.25,) * 4)
    with pytest.raises(ConfigError, match="no per-pixel form"):
        cv.matching_cost(params, "mix")
    with pytest.raises(ConfigError, match="unknown variant"):
        cv.matching_cost(params, "nope")


def test_default_max_disparity_is_the_heads_range():
    assert cv.default_max_disparity(1242) == 372 and cv.default_max_disparity(100) == 30


def test_shifted_is_the_losses_reconstruction():
    """``shifted(right, d)`` is training's reconstruction of the left view at disparity d (border)."""
    right = torch.rand(3, H, W)
    for d in (0, 1, 7, D):
        disp = torch.full((1, 1, H, W), d / W)
        expected = reconstruct(right[None], right[None], disp, disp, "border")[:1]
        torch.testing.assert_close(cv.shifted(right, [d]), expected, atol=1e-5, rtol=0)


@pytest.mark.parametrize("name", sorted(COSTS))
def test_volume_slices_are_the_losses_appearance_map(name, monkeypatch):
    """Slice d of the volume is the per-pixel appearance cost of the right view shifted by d, built
    in several blocks of rows and disparities (odd sizes: MS-SSIM's padded pooling)."""
    monkeypatch.setattr(cv, "BLOCK_ELEMENTS", 3 * 5 * 130 * 3)
    left, right = torch.rand(3, 37, 101), torch.rand(3, 37, 101)
    volume = cv.cost_volume(left, right, COSTS[name], max_disparity=9)
    assert volume.shape == (37, 101, 10)
    for d in range(10):
        expected = cv._appearance_map(COSTS[name], cv.shifted(right, [d]), left[None])[0]
        torch.testing.assert_close(volume[..., d], expected, atol=1e-6, rtol=0)


@pytest.mark.parametrize("padding", ["valid", "reflect"])
def test_ssim_cost_averages_to_the_training_term(padding):
    """SSIM: the map's mean (over the valid interior for ``padding: valid``) is training's term."""
    params = params_with(ssim={"padding": padding})
    cost, term = cv.matching_cost(params, "ssim"), build_appearance(params, "ssim")
    estimate, target = torch.rand(2, 3, 24, 40), torch.rand(2, 3, 24, 40)
    similarity = cv._similarity_map(cost, estimate, target)
    inner = (slice(None), slice(None), slice(1, -1), slice(1, -1)) if padding == "valid" else (...,)
    dissimilarity = ((1 - similarity) / 2).clamp(0, 1)[inner].mean()
    mean = cost.alpha * dissimilarity + (1 - cost.alpha) * (estimate - target).abs().mean()
    torch.testing.assert_close(mean, term([estimate], [target])[0], atol=1e-6, rtol=0)
    whole = cv._appearance_map(cost, estimate, target).mean()
    if padding == "reflect":
        torch.testing.assert_close(whole, term([estimate], [target])[0], atol=1e-6, rtol=0)


@pytest.mark.parametrize("name", ["msssim", "msssim_k7"])
def test_ms_ssim_maps_are_trainings_and_constant_maps_give_its_value(name):
    """The level maps' means, combined as training combines them, are ``ms_ssim``; the per-pixel
    product of constant maps (each level's mean) is that value at every pixel."""
    cost = COSTS[name]
    x, y = torch.rand(2, 3, 45, 70), torch.rand(2, 3, 45, 70)
    maps = cv._level_maps(x, y, cost.kernel_size, cost.levels)
    assert [m.shape[-2:] for m in maps] == [(45, 70), (23, 35), (12, 18), (6, 9)]
    training = ms_ssim(x, y, cost.kernel_size, cost.levels, cost.weights, padding="same")
    means = [m.mean((2, 3), keepdim=True) for m in maps]
    combined = torch.prod(
        torch.stack([m.clamp(min=1e-6) ** w for m, w in zip(means, cost.weights, strict=True)]), 0
    )
    torch.testing.assert_close(combined.mean(1).flatten(), training, atol=1e-6, rtol=1e-5)
    constant = cv._collapse(
        [mean.expand_as(m).clone() for mean, m in zip(means, maps, strict=True)], cost.weights
    )
    torch.testing.assert_close(
        constant.mean(1), training.view(2, 1, 1).expand(2, 45, 70), atol=1e-6, rtol=1e-5
    )


def test_ms_ssim_floor_is_trainings():
    """Anticorrelated images (y = 1 - x) have negative contrast-structure at every level, which
    training floors before the power: the per-pixel form's floor gives the same value."""
    x = torch.rand(1, 3, 32, 48)
    y = 1 - x
    weights = (0.25, 0.25, 0.25, 0.25)
    maps = cv._level_maps(x, y, 3, 4)
    assert all(float(m.mean()) < 0 for m in maps)
    constant = cv._collapse([m.mean((2, 3), keepdim=True).expand_as(m).clone() for m in maps], weights)
    training = ms_ssim(x, y, 3, 4, weights, padding="same")
    torch.testing.assert_close(constant.mean(1)[0, 0, 0], training[0], rtol=1e-6, atol=0)
    assert float(training[0]) == pytest.approx(cv.MS_SSIM_FLOOR, rel=1e-5)


def test_upsample_aligns_with_the_pooling_cells():
    """A linear ramp pooled by training's 2x2 (odd sizes pad one px each side) and upsampled back is
    the ramp again away from the edges: the cells' centres are where :func:`upsample` puts them."""
    for size in (20, 21):
        ramp = torch.arange(size, dtype=torch.float32).view(1, 1, 1, size).expand(1, 1, 4, size)
        coarse = cv.pyramid(ramp.contiguous(), 2)[1]
        back = cv._upsample(coarse, (4, size))
        torch.testing.assert_close(back[..., 2:-2], ramp[..., 2:-2], atol=1e-5, rtol=0)


@pytest.mark.parametrize("name", sorted(COSTS))
def test_volume_argmin_recovers_an_integer_shift(name):
    left, right = tensors(*scene(6, 6)[:2])
    truth = 6
    best = cv.winner_take_all(cv.cost_volume(left, right, COSTS[name], max_disparity=D))
    inner = best[4:-4, D + 4 : -8]
    assert (inner == truth).float().mean() > 0.97


# ----------------------------------------------------------------------------- SGM


def test_path_step_known_answer():
    previous = torch.tensor([[0.0, 5.0, 5.0, 5.0]])
    step = _path_step(torch.tensor([[1.0, 1.0, 1.0, 1.0]]), previous, 1.0, 3.0)
    # min(prev(d), prev(d±1) + 1, min + 3) - min, plus the cost
    torch.testing.assert_close(step, torch.tensor([[1.0, 2.0, 4.0, 4.0]]))


def test_aggregate_without_penalties_is_paths_times_cost():
    volume = torch.rand(5, 7, 4)
    for paths in (4, 8):
        torch.testing.assert_close(_aggregate(volume, 0.0, 0.0, paths), paths * volume)


def test_subpixel_is_the_parabolas_vertex():
    costs = torch.tensor([[[4.0, 1.0, 2.0, 9.0], [1.0, 2.0, 3.0, 4.0], [5.0, 5.0, 5.0, 5.0]]])
    refined = _subpixel(costs, costs.argmin(-1))
    # (c0 - c2) / (2 (c0 - 2 c1 + c2)) = 2/8; the edge and the flat row stay put
    torch.testing.assert_close(refined, torch.tensor([[1.25, 0.0, 0.0]]))


def test_right_disparity_reindexes_the_left_volume():
    volume = torch.rand(19, 30, 7)
    expected = torch.empty(19, 30, dtype=torch.long)
    for y in range(19):
        for x in range(30):
            costs = [volume[y, x + d, d] if x + d < 30 else torch.inf for d in range(7)]
            expected[y, x] = int(np.argmin(costs))
    assert torch.equal(_right_disparity(volume), expected)


def test_lr_valid_tolerance_and_the_image_edge():
    left = torch.tensor([[0.0, 2.0, 1.0, 1.4, 1.6]])
    right = torch.tensor([[0, 1, 0, 3, 0]])
    # x=0: match 0, right 0: ok; x=1: match -1: outside; x=2: match 1 (1 vs 1); x=3: match 2 (1.4 vs 0);
    # x=4: match round(2.4) = 2 (1.6 vs 0: off by 1.6)
    assert _lr_valid(left, right, 1.0).tolist() == [[True, False, True, False, False]]
    assert _lr_valid(left, right, 1.5).tolist() == [[True, False, True, True, False]]


def test_fill_holes_takes_the_lower_neighbour():
    disparity = np.array([[9, 4, 7, 7, 2, 8], [9, 9, 9, 9, 9, 9], [5, 6, 3, 8, 8, 1]], dtype=np.float32)
    valid = np.array([[0, 1, 0, 0, 1, 0], [0, 0, 0, 0, 0, 0], [1, 1, 1, 1, 1, 1]], dtype=bool)
    expected = [[4, 4, 2, 2, 2, 2], [0] * 6, [5, 6, 3, 8, 8, 1]]
    assert fill_holes(disparity, valid).tolist() == expected


@pytest.mark.parametrize("name", ["ssim", "msssim"])
def test_sgm_recovers_a_fronto_parallel_plane(name):
    left, right = tensors(*scene(5, 5)[:2])
    disparity, valid = sgm(cv.cost_volume(left, right, COSTS[name], max_disparity=D))
    assert np.mean(np.abs(disparity[:, D:] - 5) < 0.25) > 0.98 and valid[:, D:].mean() > 0.98


def test_sgm_is_sub_pixel_on_a_non_integer_shift():
    left, right = tensors(*scene(5.4, 5.4)[:2])
    disparity, _ = sgm(cv.cost_volume(left, right, COSTS["ssim"], max_disparity=D))
    error = np.abs(disparity[2:-2, D:-2] - 5.4)
    assert np.median(error) < 0.2 and error.mean() < 0.25


def test_sgm_two_planes_lr_check_and_filling():
    """A foreground box at 11 px over a background at 3 px: both planes recovered; the 8 px band
    left of the box, hidden from the right view, fails the left-right check and is filled with
    the background's disparity (its lower neighbour)."""
    box = (64, 8, 104, 32)
    left, right, truth = scene(11, 3, box)
    disparity, valid = sgm(cv.cost_volume(*tensors(left, right), COSTS["ssim"], max_disparity=D))
    error = np.abs(disparity - truth)
    edges = np.zeros((H, W), dtype=bool)
    edges[box[1] - 2 : box[3] + 2, box[0] - 10 : box[0] + 2] = True
    edges[box[1] - 2 : box[3] + 2, box[2] - 2 : box[2] + 2] = True
    edges[box[1] - 2 : box[1] + 2] = edges[box[3] - 2 : box[3] + 2] = True
    interior = ~edges
    interior[:, :D] = False
    assert np.mean(error[interior] <= 0.5) > 0.97
    band = (slice(box[1] + 2, box[3] - 2), slice(box[0] - 7, box[0] - 2))  # the occluded band, less its edges
    assert valid[band].mean() < 0.2 and valid[interior].mean() > 0.95
    # The background's side (the box is at 11 px); an occlusion edge's pixel may sit between.
    assert np.all(disparity[band] < 7) and np.median(np.abs(disparity[band] - 3)) < 1


def test_sgm_config_checks():
    with pytest.raises(ValueError, match="paths"):
        SGMConfig(paths=6)
    with pytest.raises(ValueError, match="p1 <= p2"):
        SGMConfig(p1=2.0, p2=1.0)


# ----------------------------------------------------------------------------- SGBM


def test_sgbm_recovers_a_shifted_texture():
    left, right = ((np.clip(i, 0, 1) * 255).round().astype(np.uint8) for i in scene(6, 6)[:2])
    disparity, valid = sgbm_disparity(left, right, max_disparity=D)
    assert disparity.shape == (H, W) and disparity.dtype == np.float32
    assert np.mean(np.abs(disparity[4:-4, 4:-4] - 6) <= 1) > 0.97 and valid[4:-4, 4:-4].mean() > 0.8
    assert _num_disparities(16) == 16 and _num_disparities(17) == 32 and _num_disparities(372) == 384


# ----------------------------------------------------------------------------- D1 and EPE


def test_stereo_errors_known_answer():
    gt = np.array([[0, 10, 100], [50, 2, 0]], dtype=np.float32)
    pred = np.array([[7, 13.5, 104], [52, 6, 99]], dtype=np.float32)
    # GT 10 -> 13.5: 3.5 > 3 and > 0.5, out; 100 -> 104: 4 <= 5 % of 100, in; 50 -> 52 in; 2 -> 6 out
    errors = stereo_errors(gt, pred)
    assert errors["d1"] == pytest.approx(0.5)
    assert errors["epe"] == pytest.approx((3.5 + 4 + 2 + 4) / 4)


def test_stereo_errors_thresholds_are_strict():
    gt = np.array([60.0, 100.0, 10.0])
    assert stereo_errors(gt, gt + np.array([3.0, 5.0, 3.01]))["d1"] == pytest.approx(1 / 3)
    assert stereo_errors(gt, gt) == {"d1": 0.0, "epe": 0.0}


def test_stereo_errors_refuses_bad_input():
    with pytest.raises(ValueError, match="no GT"):
        stereo_errors(np.zeros(3), np.ones(3))
    with pytest.raises(ValueError, match="one shape"):
        stereo_errors(np.ones(3), np.ones(4))
    with pytest.raises(ValueError, match="not finite"):
        stereo_errors(np.ones(2), np.array([1.0, np.nan]))


# ----------------------------------------------------------------------------- real KITTI frames


def kitti2015(frame: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if not KITTI2015.is_dir():
        pytest.skip("../shared/real-samples is not available")
    return (
        read_image(KITTI2015 / "image_2" / f"{frame}.png"),
        read_image(KITTI2015 / "image_3" / f"{frame}.png"),
        read_disparity(KITTI2015 / "disp_occ_0" / f"{frame}.png"),
    )


def test_sgbm_on_real_kitti_2015():
    """Full size, D = 0.3·W; measured D1 6.8 % on this frame (10.3 % on 000000_10)."""
    left, right, gt = kitti2015("000001_10")
    disparity, _ = sgbm_disparity(left, right)
    assert stereo_errors(gt, disparity)["d1"] < 0.10


def test_ssim_cost_volume_start_on_real_kitti_2015():
    """The SSIM cost's SGM start at half size (area-resized as training resizes; GT sampled at even
    pixels and halved, so 3 px there are 6 px at full size; D = 0.3·W): measured D1 3.4 % on this
    frame (4.0 % on 000000_10), its raw winner-take-all 33 % (42 %)."""
    left, right, gt = kitti2015("000001_10")
    size = (gt.shape[1] // 2, gt.shape[0] // 2)
    small = [to_tensor(cv2.resize(i, size, interpolation=cv2.INTER_AREA)) for i in (left, right)]
    gt_small = gt[: 2 * size[1] : 2, : 2 * size[0] : 2] / 2
    volume = cv.cost_volume(*small, COSTS["ssim"])
    start = stereo_errors(gt_small, sgm(volume)[0])["d1"]
    assert start < 0.08
    assert stereo_errors(gt_small, cv.winner_take_all(volume).numpy())["d1"] > 3 * start


def test_the_cost_volume_is_bounded_before_it_is_allocated() -> None:
    # Issue 42 (bounded memory): the volume grows with H·W²; the optimum CLI's own-size limit
    # (4096 x 4096 px) would have asked for ~150 GiB. Known answers: KITTI's size fits, 4096² does not.
    assert cv._volume_bytes(375, 1242) == 375 * 1242 * 373 * cv.VOLUME_BYTES_PER_CELL
    cv.check_volume_size(375, 1242)
    with pytest.raises(
        DataError, match=r"4096 x 4096 px pair at 1229 disparities would take about 153\.6 GiB"
    ):
        cv.check_volume_size(4096, 4096)
    # A broadcast (zero-memory) view of a huge pair: refused before the volume is allocated.
    huge = torch.zeros(3, 1, 1).expand(3, 2048, 4096)
    with pytest.raises(DataError, match="over the cost start's 8 GiB"):
        cv.cost_volume(huge, huge, cv.MatchingCost(0.85, 3, ()))
