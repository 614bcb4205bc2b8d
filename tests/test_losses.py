"""Tests of SSIM, MS-SSIM (fast kernels against the reference formula and pytorch-msssim), the
Monodepth loss terms, the appearance terms and MonodepthLoss."""

from __future__ import annotations

import math
import subprocess
import sys
import typing
from typing import Callable

import pytest
import torch
import torch.nn.functional as F

from msdepth.config.params import LossConfig
from msdepth.config.variants import configs
from msdepth.config.variants.msssim import MSSSIMConfig
from msdepth.config.variants.ssim import SSIMConfig
from msdepth.losses import ssim_kernels as kernels
from msdepth.losses.appearance import terms
from msdepth.losses.appearance.msssim import _msssim_similarity
from msdepth.losses.monodepth import (
    AppearanceTerm,
    MonodepthLoss,
    _lr_consistency_loss,
    appearance_loss,
    scale_pyramid,
    smoothness_loss,
)
from msdepth.losses.ssim import (
    C1,
    C2,
    WANG_WEIGHTS,
    LearnedLevelWeights,
    _reference_ssim_terms,
    level_weights,
    ms_ssim,
    ms_ssim_pyramid,
    ssim,
)

_ssim_terms = kernels.ssim_terms


def _rand(*shape: int, seed: int = 0) -> torch.Tensor:
    return torch.rand(*shape, generator=torch.Generator().manual_seed(seed))


def _noisy(x: torch.Tensor, std: float, seed: int = 1) -> torch.Tensor:
    noise = torch.randn(x.shape, generator=torch.Generator().manual_seed(seed))
    return (x + std * noise).clamp(0, 1)


# Pairs on which SSIM-type losses are numerically delicate: negative cs, zero variance, zero means.
ADVERSARIAL: dict[str, Callable[[], tuple[torch.Tensor, torch.Tensor]]] = {
    "anticorrelated": lambda: (_rand(2, 3, 32, 64), 1 - _rand(2, 3, 32, 64)),
    "zeros": lambda: (torch.zeros(2, 3, 32, 64), torch.zeros(2, 3, 32, 64)),
    "ones": lambda: (torch.ones(2, 3, 32, 64), torch.ones(2, 3, 32, 64)),
    "constant_vs_noise": lambda: (torch.full((2, 3, 32, 64), 0.5), _rand(2, 3, 32, 64)),
    "random": lambda: (_rand(2, 3, 32, 64, seed=3), _rand(2, 3, 32, 64, seed=4)),
}


# ----------------------------------------------------------------------------- SSIM


def _plain_ssim_terms(
    x: torch.Tensor, y: torch.Tensor, kernel_size: int, window: str, padding: str
) -> tuple[torch.Tensor, torch.Tensor]:
    """The SSIM formula written out with autograd (the module's reference): (cs map, SSIM map)."""
    return _reference_ssim_terms(x, y, kernel_size, window, 1.5, padding)  # type: ignore[arg-type]


@pytest.mark.parametrize("kernel_size", [1, 3, 5, 7, 9, 11])
@pytest.mark.parametrize("padding", ["valid", "same"])
@pytest.mark.parametrize("size", [(13, 21), (4, 6)])
@pytest.mark.parametrize("window", ["box", "gaussian"])
def test_ssim_terms_match_the_plain_formula(
    kernel_size: int, padding: str, size: tuple[int, int], window: str
) -> None:
    """The fused SSIM terms (hand-written backward) equal autograd through the written-out formula.

    In float64: in float32 both sides carry E[x²] - μ² cancellation noise (for k = 1 the
    variances are pure noise), which the comparison would measure instead of the formula.
    """
    if padding == "valid" and min(size) < kernel_size:
        pytest.skip("no valid window")
    x = _rand(2, 5, *size).double().requires_grad_()
    y = _noisy(x.detach(), 0.2).requires_grad_()
    cs, full = _ssim_terms(x, y, kernel_size, window, 1.5, padding, luminance=True)  # type: ignore[arg-type]
    ref_cs, ref_full = _plain_ssim_terms(x, y, kernel_size, window, padding)
    torch.testing.assert_close(cs, ref_cs, rtol=0, atol=1e-10)
    torch.testing.assert_close(full, ref_full, rtol=0, atol=1e-10)
    up_cs, up_full = _rand(*cs.shape, seed=8).double(), _rand(*cs.shape, seed=9).double()
    ours = torch.autograd.grad((cs * up_cs + full * up_full).sum(), (x, y))
    ref = torch.autograd.grad((ref_cs * up_cs + ref_full * up_full).sum(), (x, y))
    for a, b in zip(ours, ref, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-7, atol=1e-8)
    cs_only = _ssim_terms(x, y, kernel_size, window, 1.5, padding, luminance=False)  # type: ignore[arg-type]
    assert torch.equal(cs_only, cs)


@pytest.mark.parametrize(
    ("kernel_size", "padding", "size"),
    [
        (3, "valid", (5, 7)),
        (3, "same", (5, 7)),
        (5, "same", (6, 5)),
        (7, "same", (4, 6)),
        (1, "valid", (3, 4)),
    ],
)
@pytest.mark.parametrize("window", ["box", "gaussian"])
@pytest.mark.parametrize("luminance", [False, True])
def test_ssim_terms_gradcheck(
    kernel_size: int, padding: str, size: tuple[int, int], window: str, luminance: bool
) -> None:
    """float64 gradcheck of the hand-written backward, including images smaller than the window."""
    x = _rand(2, 2, *size, seed=3).double().requires_grad_()
    y = _rand(2, 2, *size, seed=4).double().requires_grad_()
    fn = lambda a, b: _ssim_terms(a, b, kernel_size, window, 1.5, padding, luminance)  # noqa: E731
    assert torch.autograd.gradcheck(fn, (x, y))


@pytest.mark.parametrize("needs", ["x", "y"])
@pytest.mark.parametrize("luminance", [False, True])
def test_ssim_terms_gradcheck_one_input(needs: str, luminance: bool) -> None:
    """Only one input needs a gradient: the backward then filters its μ map alone."""
    x = _rand(2, 2, 7, 9, seed=3).double().requires_grad_(needs == "x")
    y = _rand(2, 2, 7, 9, seed=4).double().requires_grad_(needs == "y")
    fn = lambda a, b: _ssim_terms(a, b, 5, "box", 1.5, "same", luminance)  # noqa: E731
    assert torch.autograd.gradcheck(fn, (x, y))


def test_ssim_terms_unused_output_and_target_without_gradient() -> None:
    """Only the SSIM output used, the target constant: same gradient as the plain formula."""
    x, y = _rand(2, 3, 9, 11).requires_grad_(), _noisy(_rand(2, 3, 9, 11), 0.1)
    (grad,) = torch.autograd.grad(_ssim_terms(x, y, 3, "box", 1.5, "same", True)[1].sum(), x)
    (ref,) = torch.autograd.grad(_plain_ssim_terms(x, y, 3, "box", "same")[1].sum(), x)
    torch.testing.assert_close(grad, ref, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("needs", ["x", "y", "both"])
def test_ssim_terms_chunking_does_not_change_results(monkeypatch: pytest.MonkeyPatch, needs: str) -> None:
    """Planes processed a few at a time (a partial last chunk too) give the same values and
    gradients, whichever inputs need one (the backward filters one μ map per such input)."""
    x, y = _rand(3, 3, 20, 30), _noisy(_rand(3, 3, 20, 30), 0.1)
    inputs = [t.requires_grad_() for t, name in ((x, "x"), (y, "y")) if needs in (name, "both")]

    def run() -> tuple[torch.Tensor, ...]:
        cs, full = _ssim_terms(x, y, 5, "box", 1.5, "same", True)
        return (cs, full, *torch.autograd.grad((cs + 2 * full).sum(), inputs))

    whole = run()
    monkeypatch.setattr(kernels, "_CHUNK_ELEMENTS", 4 * 4 * 24 * 34)  # 4 planes per chunk, 9 planes
    for a, b in zip(whole, run(), strict=True):
        assert torch.equal(a, b)


def test_ssim_terms_chunk_only_on_the_cpu() -> None:
    """Cache-sized chunks on the CPU; on a GPU every plane at once (each chunk is ~70 kernel
    launches, and at the seed's 256x512 the CPU budget would be one plane per chunk)."""
    per_plane = 4 * 258 * 514  # four padded maps of a 256x512 image, 3x3 window
    assert kernels._planes_per_chunk(torch.device("cpu"), 48, per_plane) == 1
    assert kernels._planes_per_chunk(torch.device("cpu"), 48, 4 * 66 * 194) == 10
    assert kernels._planes_per_chunk(torch.device("cpu"), 3, 4 * 66 * 194) == 3
    assert kernels._planes_per_chunk(torch.device("cuda"), 48, per_plane) == 48
    # Bounded on the GPU too: about 1 GiB of fp32 maps per chunk.
    assert kernels._planes_per_chunk(torch.device("cuda"), 10_000, per_plane) == (1 << 28) // per_plane


@pytest.mark.parametrize("kernel_size", [1, 3, 5, 7, 9, 11, 13, 15])
def test_box_sum_1d(kernel_size: int) -> None:
    x = _rand(2, 3, 17, 19).double()
    before = x.clone()
    for dim in (-1, -2):
        expected = x.unfold(dim % 4, kernel_size, 1).sum(-1)
        torch.testing.assert_close(kernels._box_sum_1d(x, kernel_size, dim), expected)
    assert torch.equal(x, before)


@pytest.mark.parametrize("kernel_size", [1, 3, 7, 11])
@pytest.mark.parametrize("padding", ["valid", "reflect"])
@pytest.mark.parametrize("window", ["box", "gaussian"])
def test_ssim_fast_matches_reference(kernel_size: int, padding: str, window: str) -> None:
    """ssim()'s two implementations: the same map and gradients (float64)."""
    x = _rand(2, 3, 15, 23).double().requires_grad_()
    y = _noisy(x.detach(), 0.2)
    out = {
        impl: ssim(x, y, kernel_size, padding, window, implementation=impl)  # type: ignore[arg-type]
        for impl in ("fast", "reference")
    }
    torch.testing.assert_close(out["fast"], out["reference"], rtol=0, atol=1e-10)
    up = _rand(*out["fast"].shape, seed=5).double()
    fast, ref = (torch.autograd.grad((out[i] * up).sum(), x)[0] for i in ("fast", "reference"))
    torch.testing.assert_close(fast, ref, rtol=1e-7, atol=1e-9)


@pytest.mark.parametrize(
    ("kernel_size", "levels", "padding"), [(3, 4, "same"), (7, 3, "same"), (5, 2, "valid")]
)
@pytest.mark.parametrize("window", ["box", "gaussian"])
def test_ms_ssim_pyramid_fast_matches_reference(
    kernel_size: int, levels: int, padding: str, window: str
) -> None:
    """The batched kernels and the one-level-at-a-time reference agree on a pyramid (float64)."""
    xs = [_rand(2, 3, 32 >> s, 48 >> s, seed=s).double().requires_grad_() for s in range(3)]
    if padding == "valid":
        xs = xs[:1]
    ys = [_noisy(x.detach(), 0.1, seed=10 + i) for i, x in enumerate(xs)]
    out = {
        impl: ms_ssim_pyramid(xs, ys, kernel_size, levels, "wang", window, 1.5, padding, impl)  # type: ignore[arg-type]
        for impl in ("fast", "reference")
    }
    torch.testing.assert_close(out["fast"], out["reference"], rtol=0, atol=1e-10)
    up = _rand(*out["fast"].shape, seed=6).double()
    fast, ref = (torch.autograd.grad((out[i] * up).sum(), xs) for i in ("fast", "reference"))
    for a, b in zip(fast, ref, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-7, atol=1e-9)


def test_reference_implementation_rejects_levels_smaller_than_the_window_and_unknown_names() -> None:
    x = _rand(1, 3, 8, 24)
    with pytest.raises(ValueError, match="smaller than"):
        ms_ssim(x, x, kernel_size=3, levels=4, padding="valid", implementation="reference")
    with pytest.raises(ValueError, match="implementation"):
        ssim(x, x, implementation="slow")  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("appearance", "weights"), [("ssim", "wang"), ("msssim", "wang"), ("msssim", "learned")]
)
def test_monodepth_loss_reference_kernels_match_fast(appearance: str, weights: str) -> None:
    """``loss.kernels: reference`` (the fallback) gives the fast loss and gradients up to rounding."""
    left, right = _stereo_pair(shift=8)
    terms, grads = {}, {}
    for impl in ("fast", "reference"):
        disps = [
            (d * (1 + _rand(*d.shape, seed=i))).requires_grad_() for i, d in enumerate(_constant_disps(8))
        ]
        loss = _loss(appearance, weights, kernels=impl)
        terms[impl] = loss(disps, left, right)
        grads[impl] = torch.autograd.grad(terms[impl]["total"], [*disps, *loss.parameters()])
    for k in terms["fast"]:
        torch.testing.assert_close(terms["fast"][k], terms["reference"][k], rtol=1e-5, atol=1e-6)
    for a, b in zip(grads["fast"], grads["reference"], strict=True):
        torch.testing.assert_close(a, b, rtol=1e-3, atol=1e-6)


def test_monodepth_loss_state_keeps_the_checkpoint_names() -> None:
    """The term's learned weights are the loss's own ``level_weights``: checkpoints written before
    the registry load as they are."""
    assert list(_loss("msssim", "learned").state_dict()) == ["level_weights.logits"]
    assert list(_loss("ssim").state_dict()) == []


@pytest.mark.parametrize("size", [(8, 12), (7, 12), (8, 13), (1, 3)])
def test_downsample_is_pytorch_msssim_average_pooling(size: tuple[int, int]) -> None:
    x = _rand(2, 3, *size).requires_grad_()
    out = kernels.downsample(x)
    ref = F.avg_pool2d(x, 2, padding=[s % 2 for s in size])
    torch.testing.assert_close(out, ref, rtol=0, atol=1e-7)
    up = _rand(*out.shape, seed=2)
    torch.testing.assert_close(
        torch.autograd.grad((out * up).sum(), x)[0], torch.autograd.grad((ref * up).sum(), x)[0]
    )


@pytest.mark.parametrize("padding", ["valid", "reflect"])
def test_ssim_of_image_with_itself_is_one(padding: str) -> None:
    x = _rand(2, 3, 10, 12)
    assert torch.allclose(ssim(x, x, padding=padding), torch.ones(()), atol=1e-5)


def test_ssim_is_symmetric() -> None:
    x, y = _rand(2, 3, 10, 12), _rand(2, 3, 10, 12, seed=1)
    assert torch.allclose(ssim(x, y), ssim(y, x))


def test_ssim_of_constant_images_is_the_luminance_term() -> None:
    a, b = 0.2, 0.7
    # float64: in float32, E[x²] - μ² leaves ~1e-8 of cancellation noise in the variances.
    f64 = torch.float64
    s = ssim(torch.full((1, 1, 6, 6), a, dtype=f64), torch.full((1, 1, 6, 6), b, dtype=f64))
    # Zero variances make the contrast-structure term exactly 1.
    expected = (2 * a * b + C1) / (a * a + b * b + C1)
    assert torch.allclose(s, torch.full_like(s, expected), atol=1e-10)


@pytest.mark.parametrize("kernel_size", [3, 5])
def test_ssim_shapes(kernel_size: int) -> None:
    x = _rand(2, 3, 10, 12)
    assert ssim(x, x, kernel_size, "valid").shape == (2, 3, 10 - kernel_size + 1, 12 - kernel_size + 1)
    assert ssim(x, x, kernel_size, "reflect").shape == (2, 3, 10, 12)


def test_ssim_hand_computed_on_3x3() -> None:
    xs = [0.1, 0.4, 0.9, 0.3, 0.5, 0.2, 0.8, 0.6, 0.7]
    ys = [0.2, 0.3, 0.8, 0.4, 0.4, 0.1, 0.9, 0.5, 0.9]
    n = len(xs)
    mx, my = sum(xs) / n, sum(ys) / n
    vx = sum(v * v for v in xs) / n - mx * mx
    vy = sum(v * v for v in ys) / n - my * my
    cov = sum(a * b for a, b in zip(xs, ys, strict=True)) / n - mx * my
    expected = (2 * mx * my + C1) * (2 * cov + C2) / ((mx * mx + my * my + C1) * (vx + vy + C2))
    x = torch.tensor(xs, dtype=torch.float64).view(1, 1, 3, 3)
    y = torch.tensor(ys, dtype=torch.float64).view(1, 1, 3, 3)
    out = ssim(x, y)
    assert out.shape == (1, 1, 1, 1)
    assert out.item() == pytest.approx(expected, abs=1e-12)


def test_ssim_reflect_matches_explicit_reflection_pad() -> None:
    x, y = _rand(1, 3, 6, 7), _rand(1, 3, 6, 7, seed=1)
    pad = lambda t: torch.nn.functional.pad(t, (1, 1, 1, 1), mode="reflect")  # noqa: E731
    assert torch.allclose(ssim(x, y, padding="reflect"), ssim(pad(x), pad(y), padding="valid"))


def test_ssim_rejects_mismatched_inputs() -> None:
    with pytest.raises(ValueError, match="same shape"):
        ssim(torch.zeros(1, 3, 8, 8), torch.zeros(1, 3, 8, 9))
    with pytest.raises(ValueError, match="odd"):
        ssim(torch.zeros(1, 3, 8, 8), torch.zeros(1, 3, 8, 8), kernel_size=4)


# ----------------------------------------------------------------------------- MS-SSIM


@pytest.mark.parametrize("window", ["box", "gaussian"])
@pytest.mark.parametrize("weights", ["wang", "equal"])
def test_ms_ssim_of_image_with_itself_is_one(window: str, weights: str) -> None:
    x = _rand(2, 3, 32, 48)
    out = ms_ssim(x, x, kernel_size=5, levels=4, weights=weights, window=window)
    assert out.shape == (2,)
    assert torch.allclose(out, torch.ones(2), atol=1e-5)


def test_ms_ssim_in_unit_range_and_decreases_with_noise() -> None:
    x = _rand(2, 3, 32, 64)
    values = [ms_ssim(x, _noisy(x, std)) for std in (0.0, 0.02, 0.05, 0.1, 0.2, 0.5)]
    for v in values:
        assert ((v >= 0) & (v <= 1 + 1e-5)).all()
    for finer, coarser in zip(values, values[1:], strict=False):
        assert (coarser < finer).all()


@pytest.mark.parametrize("size", [(180, 180), (193, 257), (256, 200)])
@pytest.mark.parametrize("seed", [0, 1])
def test_ms_ssim_matches_pytorch_msssim(size: tuple[int, int], seed: int) -> None:
    pytorch_msssim = pytest.importorskip("pytorch_msssim")
    x = _rand(2, 3, *size, seed=seed)
    y = _noisy(x, 0.15, seed=seed + 10)
    ours = ms_ssim(
        x, y, kernel_size=11, levels=5, weights="wang", window="gaussian", sigma=1.5, padding="valid"
    )
    reference = pytorch_msssim.ms_ssim(x, y, data_range=1, size_average=False)
    assert torch.allclose(ours, reference, atol=1e-5)


@pytest.mark.parametrize("seed", [0, 1])
def test_single_level_matches_pytorch_msssim_ssim(seed: int) -> None:
    pytorch_msssim = pytest.importorskip("pytorch_msssim")
    x = _rand(2, 3, 40, 56, seed=seed)
    y = _noisy(x, 0.1, seed=seed + 10)
    reference = pytorch_msssim.ssim(x, y, data_range=1, size_average=False)
    ssim_map = ssim(x, y, kernel_size=11, padding="valid", window="gaussian", sigma=1.5)
    assert torch.allclose(ssim_map.mean((2, 3)).mean(1), reference, atol=1e-6)
    one_level = ms_ssim(x, y, kernel_size=11, levels=1, window="gaussian", padding="valid")
    assert torch.allclose(one_level, reference, atol=1e-6)


@pytest.mark.parametrize("kernel_size", [3, 5, 7, 11])
@pytest.mark.parametrize("window", ["box", "gaussian"])
def test_ms_ssim_same_padding_handles_levels_smaller_than_the_window(kernel_size: int, window: str) -> None:
    # 8x24 at 4 levels: the coarsest level is 1x3 px, the coarsest training scale's case.
    x = _rand(2, 3, 8, 24)
    y = _noisy(x, 0.1)
    out = ms_ssim(x, y, kernel_size=kernel_size, levels=4, window=window)
    assert out.shape == (2,) and torch.isfinite(out).all()
    assert ((out > 0) & (out <= 1 + 1e-5)).all()
    same = ms_ssim(x, x, kernel_size=kernel_size, levels=4, window=window)
    assert torch.allclose(same, torch.ones(2), atol=1e-5)


# ms_ssim(x, y, k, 4) of the implementation before the fused SSIM terms (autograd through
# box-sum window means and the written-out formula), x = _rand(2, 3, 32, 64), y = _noisy(x, 0.1).
PREVIOUS_MS_SSIM = {
    3: [0.9379457831382751, 0.9478519558906555],
    5: [0.9429200291633606, 0.954171359539032],
    7: [0.9453763961791992, 0.9553074240684509],
    11: [0.946058452129364, 0.9563157558441162],
}


@pytest.mark.parametrize("kernel_size", list(PREVIOUS_MS_SSIM))
def test_ms_ssim_matches_the_previous_implementation(kernel_size: int) -> None:
    x = _rand(2, 3, 32, 64)
    out = ms_ssim(x, _noisy(x, 0.1), kernel_size, 4)
    torch.testing.assert_close(out, torch.tensor(PREVIOUS_MS_SSIM[kernel_size]), rtol=0, atol=5e-6)


@pytest.mark.parametrize(
    "sizes", [[(32, 64), (16, 32), (8, 16), (4, 8)], [(13, 21), (6, 10), (7, 11)], [(9, 9)]]
)
@pytest.mark.parametrize("weights", ["wang", "learned"])
def test_ms_ssim_pyramid_equals_ms_ssim_per_pair(sizes: list[tuple[int, int]], weights: str) -> None:
    """Batching same-sized levels across pairs changes nothing per image (values and gradients)."""
    xs = [_rand(2, 3, *size, seed=i).requires_grad_() for i, size in enumerate(sizes)]
    ys = [_noisy(x.detach(), 0.1, seed=10 + i) for i, x in enumerate(xs)]
    learned = LearnedLevelWeights(4)
    with torch.no_grad():
        learned.logits.copy_(torch.tensor([0.1, -0.3, 0.5, 0.0]))

    def w() -> str | torch.Tensor:
        return learned() if weights == "learned" else weights

    together = ms_ssim_pyramid(xs, ys, 5, 4, w())
    separate = torch.stack([ms_ssim(x, y, 5, 4, w()) for x, y in zip(xs, ys, strict=True)])
    torch.testing.assert_close(together, separate, rtol=0, atol=1e-7)
    up = _rand(*together.shape, seed=7)
    params = [*xs, learned.logits] if weights == "learned" else xs
    grads = torch.autograd.grad((together * up).sum(), params)
    ref = torch.autograd.grad((separate * up).sum(), params)
    for a, b in zip(grads, ref, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-8)


def test_ms_ssim_pyramid_rejects_mismatched_pairs() -> None:
    with pytest.raises(ValueError, match="same \\(B, C\\)"):
        ms_ssim_pyramid(
            [torch.zeros(2, 3, 8, 8), torch.zeros(1, 3, 4, 4)],
            [torch.zeros(2, 3, 8, 8), torch.zeros(1, 3, 4, 4)],
        )
    with pytest.raises(ValueError, match="as many"):
        ms_ssim_pyramid([torch.zeros(2, 3, 8, 8)], [])


@pytest.mark.parametrize("window", ["box", "gaussian"])
def test_ms_ssim_stays_float32_under_autocast(window: str) -> None:
    """Under bf16 autocast the window statistics still run in fp32 (E[x²] - μ² cancels in bf16)."""
    x = _rand(2, 3, 32, 64)
    y = _noisy(x, 0.1)
    expected = ms_ssim(x, y, 11, 4, window=window)  # type: ignore[arg-type]
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = ms_ssim(x, y, 11, 4, window=window)  # type: ignore[arg-type]
    assert out.dtype == torch.float32
    torch.testing.assert_close(out, expected, rtol=0, atol=1e-7)


def test_ms_ssim_valid_padding_rejects_levels_smaller_than_the_window() -> None:
    x = _rand(1, 3, 8, 24)
    with pytest.raises(ValueError, match="smaller than"):
        ms_ssim(x, x, kernel_size=3, levels=4, padding="valid")


def test_level_weights() -> None:
    like = torch.zeros(())
    assert level_weights("wang", 5, like).tolist() == pytest.approx(list(WANG_WEIGHTS))
    wang4 = level_weights("wang", 4, like)
    assert wang4.sum().item() == pytest.approx(1.0)
    assert wang4.tolist() == pytest.approx([w / sum(WANG_WEIGHTS[:4]) for w in WANG_WEIGHTS[:4]])
    assert level_weights("equal", 4, like).tolist() == pytest.approx([0.25] * 4)
    with pytest.raises(ValueError, match="3 level weights"):
        level_weights(torch.ones(4), 3, like)
    with pytest.raises(ValueError, match="weights must be"):
        level_weights("uniform", 3, like)


def test_learned_level_weights_positive_normalised_and_start_equal() -> None:
    module = LearnedLevelWeights(4)
    assert torch.allclose(module(), torch.full((4,), 0.25))
    with torch.no_grad():
        module.logits.copy_(torch.tensor([-50.0, 0.0, 3.0, 20.0]))
    w = module()
    assert (w > 0).all() and w.sum().item() == pytest.approx(1.0)


# ----------------------------------------------------------------------------- gradients


def _assert_finite_grads(*tensors: torch.Tensor) -> None:
    for t in tensors:
        assert t.grad is not None, "no gradient reached the input"
        assert torch.isfinite(t.grad).all(), "non-finite gradient"


@pytest.mark.parametrize("case", list(ADVERSARIAL))
@pytest.mark.parametrize("padding", ["valid", "reflect"])
def test_ssim_gradients_finite_on_adversarial_inputs(case: str, padding: str) -> None:
    x, y = (t.requires_grad_(True) for t in ADVERSARIAL[case]())
    ssim(x, y, padding=padding).mean().backward()
    _assert_finite_grads(x, y)


@pytest.mark.parametrize("case", list(ADVERSARIAL))
@pytest.mark.parametrize("weights", ["wang", "equal", "learned"])
@pytest.mark.parametrize("window", ["box", "gaussian"])
def test_ms_ssim_gradients_finite_on_adversarial_inputs(case: str, weights: str, window: str) -> None:
    x, y = (t.requires_grad_(True) for t in ADVERSARIAL[case]())
    learned = LearnedLevelWeights(4)
    w = learned() if weights == "learned" else weights
    out = ms_ssim(x, y, kernel_size=3, levels=4, weights=w, window=window)
    assert torch.isfinite(out).all()
    out.sum().backward()
    _assert_finite_grads(x, y)
    if weights == "learned":
        _assert_finite_grads(learned.logits)


def test_anticorrelated_images_have_negative_cs_and_tiny_ms_ssim() -> None:
    x, y = ADVERSARIAL["anticorrelated"]()
    # Check the premise (negative structure) on a single full-SSIM level, then the clamp.
    assert ssim(x, y).mean() < 0
    assert (ms_ssim(x, y) < 1e-3).all()


# ----------------------------------------------------------------------------- loss terms


def test_appearance_loss_zero_for_identical_images_and_combines_terms() -> None:
    x = _rand(2, 3, 12, 16)
    assert appearance_loss(x, x).item() == pytest.approx(0.0, abs=1e-6)
    y = _noisy(x, 0.2)
    l1 = (x - y).abs().mean()
    assert appearance_loss(x, y, alpha=0.0).item() == pytest.approx(l1.item(), rel=1e-6)
    dssim = ((1 - ssim(x, y)) / 2).clamp(0, 1).mean()
    assert appearance_loss(x, y, alpha=1.0).item() == pytest.approx(dssim.item(), rel=1e-6)
    pyramid = _msssim_similarity(MSSSIMConfig(kernel_size=3, levels=3, weights="equal"))
    msssim = lambda a, b: pyramid([a], [b])[0]  # noqa: E731
    expected = 0.85 * ((1 - ms_ssim(x, y, 3, 3, "equal")) / 2).mean() + 0.15 * l1
    assert appearance_loss(x, y, similarity=msssim).item() == pytest.approx(expected.item(), rel=1e-6)


def test_make_similarity_learned_needs_weights() -> None:
    with pytest.raises(ValueError, match="LearnedLevelWeights"):
        _msssim_similarity(MSSSIMConfig(weights="learned"))


def test_smoothness_zero_for_constant_disparity() -> None:
    disp = torch.full((2, 1, 8, 10), 0.05)
    assert smoothness_loss(disp, _rand(2, 3, 8, 10)).item() == 0.0


@pytest.mark.parametrize("transpose", [False, True])
def test_smoothness_is_down_weighted_at_image_edges(transpose: bool) -> None:
    h, w = 6, 9
    disp = torch.zeros(1, 1, h, w)
    disp[..., 4:] = 1.0  # one step of 1 between columns 3 and 4
    edge_image = torch.zeros(1, 3, h, w)
    edge_image[..., 4:] = 1.0  # an image edge at the same place
    flat_image = torch.zeros(1, 3, h, w)
    if transpose:  # the same in y: Monodepth's code would miss this one
        disp, edge_image, flat_image = (t.transpose(-1, -2) for t in (disp, edge_image, flat_image))
    assert smoothness_loss(disp, flat_image).item() == pytest.approx(1 / (w - 1))
    assert smoothness_loss(disp, edge_image).item() == pytest.approx(math.exp(-1.0) / (w - 1))


@pytest.mark.parametrize("padding_mode", ["border", "zeros"])
def test_lr_consistency(padding_mode: str) -> None:
    d = torch.full((2, 1, 8, 16), 2 / 16)
    if padding_mode == "border":
        assert _lr_consistency_loss(d, d.clone(), padding_mode).item() == pytest.approx(0.0, abs=1e-7)
    else:
        # Zeros mode reads 0 past the image: consistent except for the 2 border columns.
        assert _lr_consistency_loss(d, d.clone(), padding_mode).item() < 2 * d[0, 0, 0, 0].item() * 2.5 / 16
    assert _lr_consistency_loss(d, 2 * d, padding_mode).item() > 0.1


def test_scale_pyramid_is_area_downsampling() -> None:
    x = _rand(2, 3, 16, 40)
    pyramid = scale_pyramid(x, 4)
    assert [tuple(p.shape[-2:]) for p in pyramid] == [(16, 40), (8, 20), (4, 10), (2, 5)]
    assert pyramid[0] is x
    block_mean = x.unfold(-2, 2, 2).unfold(-2, 2, 2).mean((-1, -2))
    assert torch.allclose(pyramid[1], block_mean, atol=1e-6)
    assert torch.allclose(pyramid[3].mean((-1, -2)), x.mean((-1, -2)), atol=1e-5)


# ----------------------------------------------------------------------------- MonodepthLoss


def _stereo_pair(shift: int, h: int = 32, w: int = 64) -> tuple[torch.Tensor, torch.Tensor]:
    """A synthetic rectified pair with disparity ``shift`` px everywhere: left(x) = right(x - shift)."""
    base = _rand(2, 3, h, w + shift, seed=5)
    base = torch.nn.functional.avg_pool2d(base, 3, stride=1, padding=1, count_include_pad=False)
    return base[..., :w], base[..., shift : w + shift]


def _constant_disps(pixels: float, h: int = 32, w: int = 64, scales: int = 4) -> list[torch.Tensor]:
    return [torch.full((2, 2, h >> s, w >> s), pixels / w) for s in range(scales)]


def _monodepth_loss(loss_cfg: LossConfig, appearance: str, ssim_cfg: SSIMConfig, msssim_cfg: MSSSIMConfig):
    """MonodepthLoss with the registered term of ``appearance`` (``ssim`` or ``msssim``)."""
    cfg = {"ssim": ssim_cfg, "msssim": msssim_cfg}[appearance]
    return MonodepthLoss(loss_cfg, terms()[appearance](cfg, loss_cfg))


def _loss(appearance: str = "ssim", weights: str = "wang", **loss_kwargs: object) -> MonodepthLoss:
    return _monodepth_loss(
        LossConfig(**loss_kwargs),  # type: ignore[arg-type]
        appearance,
        SSIMConfig(),
        MSSSIMConfig(kernel_size=3, levels=4, weights=weights),  # type: ignore[arg-type]
    )


def test_every_variant_has_one_term_built_from_its_config() -> None:
    """The two registries (configs in msdepth.config.variants, terms in msdepth.losses.appearance) name the
    same variants, and each term takes its own variant's config class (and keeps it)."""
    assert list(terms()) == list(configs()) and len(terms()) >= 3
    for name, term in terms().items():
        config = configs()[name]
        assert typing.get_type_hints(term.__init__)["cfg"] is config, name
        built = term(config(), LossConfig())
        assert isinstance(built, AppearanceTerm) and built.cfg == config(), name


def test_registry_refuses_a_second_class_under_a_name_and_finds_the_package_modules() -> None:
    from msdepth.config.variants._registry import Registry

    class A: ...

    class B: ...

    registry = Registry("msdepth.config.variants", "variant")
    assert set(registry.entries()) == set()  # the package's modules were imported before: no re-registration
    registry.add("x", A)
    registry.add("x", A)  # the same class again (a module imported twice) is fine
    with pytest.raises(ValueError, match="variant 'x' is registered twice"):
        registry.add("x", B)
    assert dict(registry.entries()) == {"x": A}
    # A fresh process: the first lookup imports every variant module, which registers itself.
    code = "from msdepth.config.variants import configs; print(' '.join(configs()))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert {"ssim", "msssim", "mix"} <= set(out.split())


@pytest.mark.parametrize("appearance", ["ssim", "msssim"])
def test_monodepth_loss_prefers_the_true_disparity(appearance: str) -> None:
    # 8 px at full size is exactly 1 px at 1/8, so every scale sees an exact integer shift.
    left, right = _stereo_pair(shift=8)
    loss = _loss(appearance)
    right_terms = loss(_constant_disps(8), left, right)
    assert set(right_terms) == {"total", "appearance", "smoothness", "lr_consistency"}
    assert right_terms["smoothness"].item() == pytest.approx(0.0, abs=1e-7)
    assert right_terms["lr_consistency"].item() == pytest.approx(0.0, abs=1e-6)
    for wrong in (0, 3, 16):
        wrong_terms = loss(_constant_disps(wrong), left, right)
        assert right_terms["appearance"] < 0.3 * wrong_terms["appearance"]


def test_monodepth_loss_total_combines_the_terms() -> None:
    left, right = _stereo_pair(shift=8)
    disps = [d * (1 + _rand(*d.shape, seed=i)) for i, d in enumerate(_constant_disps(8))]
    terms = _loss(smoothness_weight=0.1, lr_weight=2.0)(disps, left, right)
    expected = terms["appearance"] + 0.1 * terms["smoothness"] + 2.0 * terms["lr_consistency"]
    assert torch.allclose(terms["total"], expected)
    manual = sum(
        (smoothness_loss(d[:, :1], l_s) + smoothness_loss(d[:, 1:], r_s)) / 2**s
        for s, (d, l_s, r_s) in enumerate(zip(disps, scale_pyramid(left), scale_pyramid(right), strict=True))
    )
    assert torch.allclose(terms["smoothness"], manual)


# MonodepthLoss(LossConfig(), appearance, SSIMConfig(), MSSSIMConfig(kernel_size=k))(...)["appearance"]
# on the disparities of test_monodepth_loss_total_combines_the_terms, before views were batched and
# the SSIM terms fused.
PREVIOUS_APPEARANCE = {
    ("ssim", 3): 1.9941600561141968,
    ("msssim", 3): 1.1224614381790161,
    ("msssim", 7): 1.1037808656692505,
}


@pytest.mark.parametrize(("appearance", "kernel_size"), list(PREVIOUS_APPEARANCE))
def test_monodepth_loss_matches_the_previous_implementation(appearance: str, kernel_size: int) -> None:
    left, right = _stereo_pair(shift=8)
    disps = [d * (1 + _rand(*d.shape, seed=i)) for i, d in enumerate(_constant_disps(8))]
    loss = _monodepth_loss(LossConfig(), appearance, SSIMConfig(), MSSSIMConfig(kernel_size=kernel_size))
    value = loss(disps, left, right)["appearance"].item()
    # The recorded values carry their own fp32 rounding: up to 1e-5 from this loss in float64.
    assert value == pytest.approx(PREVIOUS_APPEARANCE[(appearance, kernel_size)], abs=2e-5)
    exact = loss([d.double() for d in disps], left.double(), right.double())["appearance"].item()
    assert value == pytest.approx(exact, abs=5e-6)


def test_monodepth_loss_learned_weights_are_parameters() -> None:
    assert list(_loss("msssim", "wang").parameters()) == []
    assert list(_loss("ssim", "learned").parameters()) == []
    loss = _loss("msssim", "learned")
    (logits,) = list(loss.parameters())
    left, right = _stereo_pair(shift=8)
    loss(_constant_disps(5), left, right)["total"].backward()
    assert logits.grad is not None and torch.isfinite(logits.grad).all() and logits.grad.abs().sum() > 0


def test_monodepth_loss_rejects_mismatched_scales() -> None:
    left, right = _stereo_pair(shift=8)
    with pytest.raises(ValueError, match="scale 1"):
        _loss()([torch.zeros(2, 2, 32, 64), torch.zeros(2, 2, 15, 32)], left, right)


@pytest.mark.parametrize("case", list(ADVERSARIAL))
@pytest.mark.parametrize(
    ("appearance", "weights"),
    [("ssim", "wang"), ("msssim", "wang"), ("msssim", "equal"), ("msssim", "learned")],
)
@pytest.mark.parametrize("padding_mode", ["border", "zeros"])
def test_monodepth_loss_gradients_finite(case: str, appearance: str, weights: str, padding_mode: str) -> None:
    left, right = ADVERSARIAL[case]()
    left.requires_grad_(True)
    disps = [(0.3 * _rand(2, 2, 32 >> s, 64 >> s, seed=s)).requires_grad_(True) for s in range(4)]
    loss = _loss(appearance, weights, padding_mode=padding_mode)
    terms = loss(disps, left, right)
    assert all(torch.isfinite(v) for v in terms.values())
    terms["total"].backward()
    _assert_finite_grads(left, *disps, *loss.parameters())


@pytest.mark.parametrize("appearance", ["ssim", "msssim"])
def test_full_resolution_loss_of_constant_disparities_repeats_the_finest_scale(appearance: str) -> None:
    """A constant disparity upsamples to itself, so with ``loss.full_resolution`` every scale's
    appearance and left-right terms equal the finest scale's: 4x that scale's own loss."""
    left, right = _stereo_pair(shift=8)
    disps = _constant_disps(5)  # 5 px: not an integer shift at the coarse scales
    full = _loss(appearance, full_resolution=True)(disps, left, right)
    finest = _loss(appearance)(disps[:1], left, right)
    assert full["appearance"].item() == pytest.approx(4 * finest["appearance"].item(), rel=1e-6)
    per_scale = _loss(appearance)(disps, left, right)
    assert full["smoothness"].item() == pytest.approx(per_scale["smoothness"].item(), abs=1e-9)
    assert full["appearance"].item() != pytest.approx(per_scale["appearance"].item(), rel=1e-3)


def test_full_resolution_loss_warps_the_upsampled_disparity() -> None:
    """Scale 1's term at full resolution is the finest scale's loss of its bilinear upsampling."""
    left, right = _stereo_pair(shift=8)
    disps = [d * (1 + _rand(*d.shape, seed=i)) for i, d in enumerate(_constant_disps(8, scales=2))]
    full = _loss("msssim", full_resolution=True)(disps, left, right)
    up = F.interpolate(disps[1], size=left.shape[-2:], mode="bilinear", align_corners=False)
    one = _loss("msssim")
    expected = one([disps[0]], left, right)["appearance"] + one([up], left, right)["appearance"]
    assert full["appearance"].item() == pytest.approx(expected.item(), rel=1e-6)
