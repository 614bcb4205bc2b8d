"""Monodepth's self-supervised training loss, with SSIM or MS-SSIM as the appearance term.

Functional core: :func:`ssim`, :func:`ms_ssim`, :func:`appearance_loss`, :func:`smoothness_loss`,
:func:`lr_consistency_loss` and :func:`scale_pyramid` are plain functions on tensors. Two thin
modules hold state: :class:`LearnedLevelWeights` (trainable MS-SSIM level weights) and
:class:`MonodepthLoss` (the configured multi-scale loss).

Images are (B, C, H, W) in [0, 1]; disparities are (B, 1, H, W) fractions of image width.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable, Literal, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .config import LossConfig, MSSSIMConfig, SSIMConfig
from .warp import PaddingMode, warp

Similarity = Callable[[Tensor, Tensor], Tensor]
"""``similarity(x, y)``: an SSIM map (B, C, H', W') or a per-image MS-SSIM (B,); 1 = identical."""

PyramidSimilarity = Callable[[Sequence[Tensor], Sequence[Tensor]], list[Tensor]]
"""``similarity(xs, ys)``: a :data:`Similarity` of every pair ``(xs[i], ys[i])`` of a scale pyramid."""

Window = Literal["box", "gaussian"]

C1 = 0.01**2  # (K1 · data_range)², data_range = 1
C2 = 0.03**2
# Wang, Simoncelli & Bovik (2003), 5 scales fine -> coarse.
WANG_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)
# Floor for per-level MS-SSIM values before the power: d(x**w)/dx = w·x**(w-1) is unbounded as
# x -> 0+ for w < 1, so relu'd values just above 0 can overflow to inf/NaN gradients; the floor
# bounds it (about w·1e6) and makes negative contrast-structure a flat, finite region.
_MS_SSIM_EPS = 1e-6


# ----------------------------------------------------------------------------- windows


@dataclass(frozen=True)
class _Window:
    """A ``kernel_size`` window (box or Gaussian) and its zero padding (0 = valid, k//2 = same)."""

    kernel_size: int
    window: Window
    sigma: float
    pad: int

    def sum(self, x: Tensor) -> Tensor:
        """Valid, unnormalised window filter of every channel of an already padded ``x`` (no autograd).

        Box: separable sums of shifted views, H then W (see :func:`_box_sum_1d`). Measured on CPU
        (2 threads) at 8x15x64x192 and 2x15x256x512, this beat a separable depthwise
        ``conv2d``, a k x k depthwise ``conv2d`` and ``avg_pool2d`` for every k in 3..11.
        Gaussian: weighted shifted views likewise (:func:`_symmetric_sum_1d`), 2.5-3x faster
        than the depthwise ``conv2d`` pair on the chunks :class:`_SSIMTerms` filters (k = 11), and
        plain elementwise arithmetic, so autocast never lowers its precision.
        """
        k = self.kernel_size
        if self.window == "gaussian":
            g = _gaussian_weights(k, self.sigma)
            return _symmetric_sum_1d(_symmetric_sum_1d(x, g, -2), g, -1)
        return _box_sum_1d(_box_sum_1d(x, k, -2), k, -1)


def _box_sum_1d(x: Tensor, k: int, dim: int) -> Tensor:
    """Valid sum of every ``k`` consecutive entries along ``dim``, in O(log k) full-size adds.

    Sums over 1, 2, 4, ... entries are built by doubling, and the window is assembled from those
    matching the bits of ``k`` (7 = 1 + 2 + 4), in place into the widest one: 2 adds for k = 3,
    4 instead of 6 for k = 7, 5 instead of 10 for k = 11. The result may be a view.
    """
    if k == 1:
        return x
    n = x.shape[dim] - k + 1
    terms, offset, width, partial = [], 0, 1, x
    while True:
        if k & width:
            terms.append(partial.narrow(dim, offset, n))
            offset += width
        if 2 * width > k:
            break
        length = partial.shape[dim] - width
        partial = partial.narrow(dim, 0, length) + partial.narrow(dim, width, length)
        width *= 2
    acc = terms.pop()  # the widest partial sum: a fresh tensor (k > 1), safe to add into
    for term in terms:
        acc += term
    return acc


def _symmetric_sum_1d(x: Tensor, weights: Sequence[float], dim: int) -> Tensor:
    """Valid weighted sum of ``len(weights)`` consecutive entries along ``dim`` for a symmetric
    window (``weights[i] == weights[-1 - i]``): one scaled copy and k - 1 in-place axpys."""
    k = len(weights)
    n, half = x.shape[dim] - k + 1, k // 2
    acc = x.narrow(dim, half, n) * weights[half]
    for i in range(half):
        acc.add_(x.narrow(dim, i, n), alpha=weights[i]).add_(x.narrow(dim, k - 1 - i, n), alpha=weights[i])
    return acc


@functools.lru_cache(maxsize=128)
def _gaussian_weights(kernel_size: int, sigma: float) -> tuple[float, ...]:
    """Normalised 1-D Gaussian of ``kernel_size`` taps (same as pytorch-msssim's window), as the
    Python floats :func:`_symmetric_sum_1d` scales by; computed in float64, once per window."""
    coords = torch.arange(kernel_size, dtype=torch.float64) - kernel_size // 2
    g = torch.exp(-(coords**2) / (2 * sigma**2))
    return tuple((g / g.sum()).tolist())


@functools.lru_cache(maxsize=128)
def _window_mass(win: _Window, h: int, w: int, dtype: torch.dtype, device: torch.device) -> Tensor | float:
    """What a window sum over an (h, w) image is divided by to become a window mean.

    Valid: the window's total mass. Same: the mass that falls inside the image, per output pixel
    (avg_pool2d's ``count_include_pad=False``), a (1, 1, h, w) map cached per size since it
    depends on nothing else.
    """
    if win.pad:
        ones = F.pad(torch.ones(1, 1, h, w, dtype=dtype, device=device), [win.pad] * 4)
        return win.sum(ones)
    return float(win.kernel_size**2) if win.window == "box" else 1.0


def _padded(like: Tensor, batch: int, channels: int, h: int, w: int, pad: int) -> tuple[Tensor, Tensor]:
    """A (batch, channels, h + 2·pad, w + 2·pad) buffer with a zero border and its (h, w) interior.

    Writing the filter's inputs straight into the interior replaces a ``cat`` and a ``pad`` copy;
    only the interior is ever written, so the buffer can be reused for every chunk.
    """
    shape = (batch, channels, h + 2 * pad, w + 2 * pad)
    buf = like.new_zeros(shape) if pad else like.new_empty(shape)
    return buf, buf[..., pad : pad + h, pad : pad + w]


# Image planes per chunk of :class:`_SSIMTerms` are chosen so that the padded moment maps hold
# about this many elements. CPU: 2^19 (2 MiB in fp32). Measured on the 2-core CPU (8x2 images of
# 3x64x192, fwd+bwd at level 0): working on 2-4 images at a time instead of all 16 made the map
# 3x faster, because the ~10 passes over the moment maps then stay in cache. Other devices
# (CUDA): 2^28, in effect every plane at once up to a 1 GiB bound; each chunk costs ~70 kernel
# launches, and at 256x512 the CPU budget would mean one plane per chunk, 48 chunks per call.
_CHUNK_ELEMENTS = 1 << 19
_CHUNK_ELEMENTS_OTHER_DEVICES = 1 << 28


def _planes_per_chunk(device: torch.device, planes: int, elements_per_plane: int) -> int:
    """How many of ``planes`` image planes :class:`_SSIMTerms` processes at a time."""
    budget = _CHUNK_ELEMENTS if device.type == "cpu" else _CHUNK_ELEMENTS_OTHER_DEVICES
    return max(1, min(planes, budget // elements_per_plane))


class _SSIMTerms(torch.autograd.Function):
    """Per-pixel contrast-structure map ``cs`` and, with ``luminance=True``, the SSIM map
    ``luminance · cs`` too (returned as ``(cs, ssim)``).

    Same values as autograd through window means of (x, y, x², y², xy) and the SSIM formula,
    with less work: ``cs`` needs only σx² + σy², so x² + y² is filtered as one map (4 window
    sums, not 5); the hand-written backward turns the maps' gradients into gradients of the
    window means (E[x² + y²] shared), which go through the adjoint window filter together, then
    ``dx = G_μx + 2x·G_sq + y·G_xy`` (and symmetrically for y, whose μ map is skipped when y
    needs no gradient: the target, in training). That replaces autograd's ~40 full-size
    temporaries by a few in-place ops. Image planes (the B·C channels are independent) are
    processed in cache-sized chunks, forward and backward.
    """

    @staticmethod
    def forward(ctx, x: Tensor, y: Tensor, win: _Window, luminance: bool):  # type: ignore[override]
        b, c, h, w = x.shape
        k, p = win.kernel_size, win.pad
        ho, wo = h + 2 * p - k + 1, w + 2 * p - k + 1
        planes_x, planes_y = x.reshape(b * c, 1, h, w), y.reshape(b * c, 1, h, w)
        chunk = _planes_per_chunk(x.device, b * c, 4 * (h + 2 * p) * (w + 2 * p))
        buf, inner = _padded(x, chunk, 4, h, w, p)
        mass = _window_mass(win, h, w, x.dtype, x.device)
        # Kept for backward, per plane: μx, μy, 2/(σx² + σy² + C2) and, with the luminance, the
        # luminance and 1/(μx² + μy² + C1) in slots 3 and 4; slots 2, 3 first hold E[x² + y²], E[xy].
        stats = x.new_empty(b * c, 5 if luminance else 4, ho, wo)
        cs_out = x.new_empty(b * c, 1, ho, wo)
        ssim_out = x.new_empty(b * c, 1, ho, wo) if luminance else None
        for start in range(0, b * c, chunk):
            xc, yc = planes_x[start : start + chunk], planes_y[start : start + chunk]
            n = xc.shape[0]
            into = inner[:n]
            into[:, 0:1].copy_(xc)
            into[:, 1:2].copy_(yc)
            torch.mul(xc, xc, out=into[:, 2:3]).addcmul_(yc, yc)
            torch.mul(xc, yc, out=into[:, 3:4])
            st = stats[start : start + n]
            torch.div(win.sum(buf[:n]), mass, out=st[:, :4])
            mu_x, mu_y, squares, cov = st[:, :4].split(1, dim=1)
            # σx² + σy² + C2 and 2·σxy + C2, in place of the means they come from.
            denominator = squares.addcmul_(mu_x, mu_x, value=-1).addcmul_(mu_y, mu_y, value=-1).add_(C2)
            numerator = cov.addcmul_(mu_x, mu_y, value=-1).mul_(2).add_(C2)
            cs = torch.div(numerator, denominator, out=cs_out[start : start + n])
            denominator.reciprocal_().mul_(2)  # slot 2: d cs / d cov
            if ssim_out is not None:
                luminance_den = torch.mul(mu_x, mu_x).addcmul_(mu_y, mu_y).add_(C1)
                lum = torch.mul(mu_x, mu_y, out=st[:, 3:4]).mul_(2).add_(C1).div_(luminance_den)
                torch.reciprocal(luminance_den, out=st[:, 4:5])
                torch.mul(lum, cs, out=ssim_out[start : start + n])
        ctx.win, ctx.mass, ctx.chunk = win, mass, chunk
        ctx.set_materialize_grads(False)  # an unused output's gradient stays None (skipped)
        ctx.save_for_backward(x, y, stats, cs_out)
        if ssim_out is None:
            return cs_out.view(b, c, ho, wo)
        return cs_out.view(b, c, ho, wo), ssim_out.view(b, c, ho, wo)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_cs: Tensor | None, grad_ssim: Tensor | None = None):  # type: ignore[override]
        x, y, stats, cs_all = ctx.saved_tensors
        win, chunk, mass, (b, c, h, w) = ctx.win, ctx.chunk, ctx.mass, x.shape
        ho, wo = stats.shape[-2:]
        planes_x, planes_y = x.reshape(b * c, 1, h, w), y.reshape(b * c, 1, h, w)
        # Views even for mean()'s expanded gradients.
        grad_cs = None if grad_cs is None else grad_cs.reshape(b * c, 1, ho, wo)
        grad_ssim = None if grad_ssim is None else grad_ssim.reshape(b * c, 1, ho, wo)
        need_x, need_y = ctx.needs_input_grad[:2]
        if (grad_cs is None and grad_ssim is None) or not (need_x or need_y):
            return None, None, None, None
        grad_x = x.new_empty(b * c, 1, h, w) if need_x else None
        grad_y = y.new_empty(b * c, 1, h, w) if need_y else None
        # Maps through the adjoint filter: dL/dE[xy], dL/dE[x² + y²], then dL/dμ of each input
        # that needs a gradient.
        maps = 2 + need_x + need_y
        # The window mean is sum / mass, so its adjoint is the sum over (grad / mass), zero-padded
        # so that the valid sum returns the input's size (the window is symmetric: no flip).
        buf, inner = _padded(x, chunk, maps, ho, wo, win.kernel_size - 1 - win.pad)
        for start in range(0, b * c, chunk):
            st = stats[start : start + chunk]
            n = st.shape[0]
            stop = start + n
            mu_x, mu_y, a, cs = st[:, 0:1], st[:, 1:2], st[:, 2:3], cs_all[start:stop]
            g_lum = None
            if grad_ssim is not None:
                lum, inv_luminance_den = st[:, 3:4], st[:, 4:5]
                g_ssim = grad_ssim[start:stop] / mass
                g_lum = g_ssim * cs
                g = g_ssim.mul_(lum)  # d ssim / d cs = luminance
                if grad_cs is not None:
                    g += grad_cs[start:stop] / mass
            else:
                g = grad_cs[start:stop] / mass  # type: ignore[index]
            d_xy, d_sq, *d_mu_maps = inner[:n].split(1, dim=1)
            torch.mul(g, a, out=d_xy)  # dL/dE[xy]
            torch.mul(d_xy, cs, out=d_sq).mul_(-0.5)  # dL/dE[x² + y²] = -g·cs/denominator
            if g_lum is not None:
                g_lum.mul_(inv_luminance_den).mul_(2)
            xc, yc = planes_x[start:stop], planes_y[start:stop]
            # (input, the other input, own μ, other μ, gradient rows) of each input that needs one.
            wanted = [(xc, yc, mu_x, mu_y, grad_x), (yc, xc, mu_y, mu_x, grad_y)]
            wanted = [item for item in wanted if item[-1] is not None]
            for d_mu, (_, _, mu_own, mu_other, _) in zip(d_mu_maps, wanted):
                # dL/dμx = -(dL/dE[xy]·μy + 2·dL/dE[x² + y²]·μx), and symmetrically for μy; the
                # luminance adds 2·g·(μy - luminance·μx) / (μx² + μy² + C1).
                torch.mul(d_xy, mu_other, out=d_mu).addcmul_(d_sq, mu_own, value=2).neg_()
                if g_lum is not None:
                    d_mu.addcmul_(g_lum, torch.addcmul(mu_other, lum, mu_own, value=-1))
            g_xy, g_sq, *g_mu = win.sum(buf[:n]).split(1, dim=1)
            for g_mu_i, (own, other, _, _, grad) in zip(g_mu, wanted):
                torch.addcmul(g_mu_i, own, g_sq, value=2, out=grad[start:stop]).addcmul_(other, g_xy)
        return _unplane(grad_x, x), _unplane(grad_y, y), None, None


def _unplane(planes: Tensor | None, like: Tensor) -> Tensor | None:
    return None if planes is None else planes.view(like.shape)


def _ssim_terms(
    x: Tensor,
    y: Tensor,
    kernel_size: int,
    window: Window,
    sigma: float,
    padding: Literal["valid", "same"],
    luminance: bool,
) -> Tensor | tuple[Tensor, Tensor]:
    """:class:`_SSIMTerms` for a ``"valid"`` or ``"same"`` window: ``cs``, or ``(cs, ssim)``."""
    pad = kernel_size // 2 if padding == "same" else 0
    return _SSIMTerms.apply(x, y, _Window(kernel_size, window, sigma, pad), luminance)


def _check_pair(name: str, x: Tensor, y: Tensor) -> None:
    if x.dim() != 4 or x.shape != y.shape:
        raise ValueError(
            f"{name}: expected two (B, C, H, W) tensors of the same shape, "
            f"got {tuple(x.shape)} and {tuple(y.shape)}"
        )


def _check_kernel(name: str, kernel_size: int) -> None:
    if kernel_size < 1 or kernel_size % 2 != 1:
        raise ValueError(f"{name}: kernel_size must be a positive odd integer, got {kernel_size}")


# ----------------------------------------------------------------------------- SSIM


def ssim(
    x: Tensor,
    y: Tensor,
    kernel_size: int = 3,
    padding: Literal["valid", "reflect"] = "valid",
    window: Window = "box",
    sigma: float = 1.5,
) -> Tensor:
    """Per-pixel SSIM map between images in [0, 1].

    Statistics come from a ``kernel_size`` window, stride 1 (``"box"`` = average pooling, as in
    Monodepth; ``"gaussian"`` with ``sigma``, as in Wang et al. and pytorch-msssim).

    Args:
        padding: ``"valid"`` (Monodepth) returns (B, C, H-k+1, W-k+1); ``"reflect"`` (Monodepth2)
            reflection-pads by k//2 first and returns the full (B, C, H, W).

    Returns:
        The SSIM map; 1 where the images agree locally, can be negative for anticorrelated ones.
    """
    _check_pair("ssim", x, y)
    _check_kernel("ssim", kernel_size)
    if padding == "reflect":
        pad = kernel_size // 2
        x = F.pad(x, (pad, pad, pad, pad), mode="reflect")
        y = F.pad(y, (pad, pad, pad, pad), mode="reflect")
    elif padding != "valid":
        raise ValueError(f"ssim: padding must be 'valid' or 'reflect', got {padding!r}")
    if min(x.shape[-2:]) < kernel_size:
        raise ValueError(f"ssim: image {tuple(x.shape[-2:])} is smaller than the {kernel_size} px window")
    return _ssim_terms(x, y, kernel_size, window, sigma, "valid", luminance=True)[1]


# ----------------------------------------------------------------------------- MS-SSIM


def level_weights(weights: str | Tensor | Sequence[float], levels: int, like: Tensor) -> Tensor:
    """Resolve an MS-SSIM weight spec to a 1-D tensor of ``levels`` weights (fine -> coarse).

    ``"wang"``: Wang et al.'s five weights truncated to ``levels`` and renormalised to sum 1
    (for 5 levels exactly Wang's list, whose rounded values sum to 1.0001); ``"equal"``:
    1/levels each; a tensor or sequence is used as given (e.g. the output of
    :class:`LearnedLevelWeights`, keeping its gradient).
    """
    if isinstance(weights, str):
        if weights == "wang":
            if not 1 <= levels <= len(WANG_WEIGHTS):
                raise ValueError(f"ms_ssim: 'wang' weights exist for 1..5 levels, got {levels}")
            w = like.new_tensor(WANG_WEIGHTS[:levels])
            # The published five sum to 1.0001 (rounding); keep them verbatim so 5 levels match
            # Wang et al. and pytorch-msssim exactly, renormalise only a truncated list.
            return w if levels == len(WANG_WEIGHTS) else w / w.sum()
        if weights == "equal":
            return like.new_full((levels,), 1.0 / levels)
        raise ValueError(f"ms_ssim: weights must be 'wang', 'equal' or a tensor, got {weights!r}")
    w = weights if isinstance(weights, Tensor) else like.new_tensor(list(weights))
    if w.shape != (levels,):
        raise ValueError(f"ms_ssim: expected {levels} level weights, got shape {tuple(w.shape)}")
    return w.to(like.dtype)


def ms_ssim(
    x: Tensor,
    y: Tensor,
    kernel_size: int = 3,
    levels: int = 4,
    weights: str | Tensor | Sequence[float] = "wang",
    window: Window = "box",
    sigma: float = 1.5,
    padding: Literal["same", "valid"] = "same",
) -> Tensor:
    """Multi-scale SSIM per image, (B,), for images in [0, 1].

    At each of ``levels`` scales the window statistics give a contrast-structure term ``cs``;
    the luminance term is used only at the coarsest scale (so the last level is full SSIM).
    Between scales both images are halved by 2x2 average pooling (padding = size % 2, exactly as
    pytorch-msssim). Each level's map is averaged over space per image and channel, and
    ``MS-SSIM = prod_l cs_l ** w_l · ssim_L ** w_L`` is then averaged over channels; with
    ``window="gaussian", kernel_size=11, sigma=1.5, levels=5, padding="valid", weights="wang"``
    this is ``pytorch_msssim.ms_ssim(x, y, data_range=1, size_average=False)``.

    Differences from pytorch-msssim, both for training: per-level values are clamped to
    ``1e-6`` instead of relu'd, so ``cs ** w`` never has an unbounded gradient when ``cs`` is
    zero, negative (anticorrelated patches) or barely positive; and ``padding="same"`` (the
    default, dissertation 3.5) lets any image of at least 1 px be used, however small against
    the window.

    Args:
        kernel_size: odd window size (dissertation: 3, 5, 7 or 11).
        levels: number of scales.
        weights: ``"wang"``, ``"equal"``, or a 1-D tensor of per-level weights (fine -> coarse).
        window: ``"box"`` (average pooling) or ``"gaussian"`` (separable, ``sigma``).
        padding: ``"same"`` (keep size, average only in-image pixels) or ``"valid"``.
    """
    _check_pair("ms_ssim", x, y)
    return ms_ssim_pyramid([x], [y], kernel_size, levels, weights, window, sigma, padding)[0]


def ms_ssim_pyramid(
    xs: Sequence[Tensor],
    ys: Sequence[Tensor],
    kernel_size: int = 3,
    levels: int = 4,
    weights: str | Tensor | Sequence[float] = "wang",
    window: Window = "box",
    sigma: float = 1.5,
    padding: Literal["same", "valid"] = "same",
) -> Tensor:
    """:func:`ms_ssim` of every pair ``(xs[i], ys[i])`` (all B images of C channels), as (len(xs), B).

    Made for a scale pyramid (pair i half the size of pair i - 1, as in :class:`MonodepthLoss`):
    pair i starts i rounds late, so its level l lines up with level i + l of pair 0, and each
    round sends all same-sized levels through the SSIM terms and the downsampling as one
    batch: 7 calls instead of 16 for 4 scales of 4 levels, where the coarse ones cost mostly
    per-call overhead. Per image the arithmetic is that of separate :func:`ms_ssim` calls;
    pairs of other sizes work too (a round then makes one call per distinct size).
    """
    n = len(xs)
    if n == 0 or len(ys) != n:
        raise ValueError(f"ms_ssim: expected as many estimates as targets (>= 1), got {n} and {len(ys)}")
    for x, y in zip(xs, ys):
        _check_pair("ms_ssim", x, y)
        if x.shape[:2] != xs[0].shape[:2]:
            raise ValueError(
                f"ms_ssim: every pair needs the same (B, C), got {tuple(xs[0].shape[:2])} "
                f"and {tuple(x.shape[:2])}"
            )
    _check_kernel("ms_ssim", kernel_size)
    if levels < 1:
        raise ValueError(f"ms_ssim: levels must be >= 1, got {levels}")
    if padding not in ("same", "valid"):
        raise ValueError(f"ms_ssim: padding must be 'same' or 'valid', got {padding!r}")
    if window not in ("box", "gaussian"):
        raise ValueError(f"ms_ssim: window must be 'box' or 'gaussian', got {window!r}")
    w = level_weights(weights, levels, xs[0])
    batch = xs[0].shape[0]
    values: list[list[Tensor]] = [[] for _ in range(n)]  # per pair, per level: (B, C)
    active: dict[int, tuple[Tensor, Tensor]] = {}  # pair -> its images at this round's level
    for round_ in range(n + levels - 1):
        if round_ < n:
            active[round_] = xs[round_], ys[round_]
        by_size: dict[tuple[int, ...], list[int]] = {}
        for i, (x, _) in active.items():
            by_size.setdefault(tuple(x.shape[-2:]), []).append(i)
        for size, pairs in by_size.items():
            if padding == "valid" and min(size) < kernel_size:
                raise ValueError(
                    f"ms_ssim: level {round_ - pairs[0]} is {size} px, smaller than the "
                    f"{kernel_size} px window; use padding='same' or fewer levels"
                )
            x = torch.cat([active[i][0] for i in pairs]) if len(pairs) > 1 else active[pairs[0]][0]
            y = torch.cat([active[i][1] for i in pairs]) if len(pairs) > 1 else active[pairs[0]][1]
            # At most one pair ends per round, the oldest active one: first in its group. Only
            # its coarsest level needs the luminance term.
            ends = round_ - pairs[0] == levels - 1
            # Means are taken over every row and sliced afterwards: slicing a map first would give
            # its backward a zero-filled full-size gradient per slice.
            if ends:
                cs, full = _ssim_terms(x, y, kernel_size, window, sigma, padding, luminance=True)
                values[pairs[0]].append(full.flatten(2).mean(-1)[:batch])
            else:
                cs = _ssim_terms(x, y, kernel_size, window, sigma, padding, luminance=False)
            going_on = pairs[1:] if ends else pairs
            if not going_on:
                continue
            skip = (len(pairs) - len(going_on)) * batch
            cs_means = cs.flatten(2).mean(-1)[skip:].split(batch)
            x, y = _downsample(x[skip:]).split(batch), _downsample(y[skip:]).split(batch)
            for j, i in enumerate(going_on):
                values[i].append(cs_means[j])
                active[i] = x[j], y[j]
        active.pop(round_ - levels + 1, None)
    stacked = torch.stack([v for pair in values for v in pair]).unflatten(0, (n, levels))  # (n, levels, B, C)
    stacked = stacked.clamp(min=_MS_SSIM_EPS)
    return torch.prod(stacked ** w.view(1, -1, 1, 1), dim=1).mean(dim=-1)


def _downsample(x: Tensor) -> Tensor:
    """pytorch-msssim's downsampling between MS-SSIM levels: 2x2 average pooling, padding = size % 2.

    Odd sizes pad 1 px and (default ``count_include_pad``) halve that edge row/column; the same
    for x and y, so x == y stays 1. Even sizes (every level of the training pyramid) take
    :class:`_Halve`, the same means 3-7x faster than ``avg_pool2d`` on CPU.
    """
    h, w = x.shape[-2:]
    if h % 2 or w % 2:
        return F.avg_pool2d(x, kernel_size=2, padding=[h % 2, w % 2])
    return _Halve.apply(x)


class _Halve(torch.autograd.Function):
    """Mean of every 2x2 block of an image of even size: two strided adds and a scale."""

    @staticmethod
    def forward(ctx, x: Tensor) -> Tensor:  # type: ignore[override]
        rows = x[..., ::2, :] + x[..., 1::2, :]
        return (rows[..., ::2] + rows[..., 1::2]).mul_(0.25)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad: Tensor) -> Tensor:  # type: ignore[override]
        # Each input pixel gets a quarter of its block's gradient (one pass, into a fresh tensor).
        b, c, h, w = grad.shape
        blocks = grad.reshape(b, c, h, 1, w, 1).expand(b, c, h, 2, w, 2)
        return torch.mul(blocks, 0.25).view(b, c, 2 * h, 2 * w)


class LearnedLevelWeights(nn.Module):
    """Trainable MS-SSIM level weights: softmax of free logits, so always positive, summing to 1.

    A softmax (rather than raw weights) means the optimiser cannot zero or negate a level to
    shortcut the loss. Initialised to equal weights.
    """

    def __init__(self, levels: int) -> None:
        super().__init__()
        if levels < 1:
            raise ValueError(f"LearnedLevelWeights: levels must be >= 1, got {levels}")
        self.logits = nn.Parameter(torch.zeros(levels))

    def forward(self) -> Tensor:
        """The current (levels,) weights."""
        return torch.softmax(self.logits, dim=0)


# ----------------------------------------------------------------------------- loss terms


def make_pyramid_similarity(
    appearance: Literal["ssim", "msssim"],
    ssim_cfg: SSIMConfig,
    msssim_cfg: MSSSIMConfig,
    learned_weights: LearnedLevelWeights | None = None,
) -> PyramidSimilarity:
    """The configured similarity for a scale pyramid: ``(xs, ys) -> [similarity(xs[i], ys[i])]``.

    SSIM runs per scale; MS-SSIM runs all scales together (:func:`ms_ssim_pyramid`). With
    ``msssim_cfg.weights == "learned"``, ``learned_weights`` must be given; it is called on
    every use so the current parameter values (and their gradient) are used.
    """
    if appearance == "ssim":
        k, padding = ssim_cfg.kernel_size, ssim_cfg.padding
        return lambda xs, ys: [ssim(x, y, kernel_size=k, padding=padding) for x, y in zip(xs, ys)]
    if appearance != "msssim":
        raise ValueError(f"appearance must be 'ssim' or 'msssim', got {appearance!r}")
    if msssim_cfg.weights == "learned" and learned_weights is None:
        raise ValueError("msssim weights 'learned' need a LearnedLevelWeights module")

    def msssim(xs: Sequence[Tensor], ys: Sequence[Tensor]) -> list[Tensor]:
        weights = msssim_cfg.weights if learned_weights is None else learned_weights()
        return list(ms_ssim_pyramid(xs, ys, msssim_cfg.kernel_size, msssim_cfg.levels, weights=weights))

    return msssim


def make_similarity(
    appearance: Literal["ssim", "msssim"],
    ssim_cfg: SSIMConfig,
    msssim_cfg: MSSSIMConfig,
    learned_weights: LearnedLevelWeights | None = None,
) -> Similarity:
    """The configured similarity function ``(x, y) -> SSIM map or per-image MS-SSIM``.

    That of :func:`make_pyramid_similarity` on a single scale (same arguments and checks).
    """
    pyramid = make_pyramid_similarity(appearance, ssim_cfg, msssim_cfg, learned_weights)
    return lambda x, y: pyramid([x], [y])[0]


def appearance_loss(
    estimate: Tensor, target: Tensor, alpha: float = 0.85, similarity: Similarity = ssim
) -> Tensor:
    """Photometric reconstruction loss ``α·mean(clip((1-S)/2, 0, 1)) + (1-α)·mean|Î - I|``.

    ``S = similarity(estimate, target)`` is an SSIM map or a per-image MS-SSIM; the mean runs
    over whatever it returns. Default: Monodepth's 3x3 box SSIM with valid padding.
    """
    return _appearance_loss(similarity(estimate, target), estimate, target, alpha)


def _appearance_loss(similarity: Tensor, estimate: Tensor, target: Tensor, alpha: float) -> Tensor:
    """:func:`appearance_loss` given the similarity ``S`` already computed."""
    dissimilarity = ((1 - similarity) / 2).clamp(0, 1)
    return alpha * dissimilarity.mean() + (1 - alpha) * (estimate - target).abs().mean()


def smoothness_loss(disp: Tensor, image: Tensor) -> Tensor:
    """Edge-aware smoothness ``mean|∂x d|·e^{-mean_c|∂x I|} + mean|∂y d|·e^{-mean_c|∂y I|}``.

    Disparity gradients are down-weighted where the image has edges (depth may jump there).
    Both directions are applied: Monodepth's TensorFlow code builds ``[x terms] + [y terms]`` as a
    Python list and then sums only its first four entries, so it only ever uses the x term — a
    known bug we do not reproduce. The caller weights this by ``smoothness_weight / 2**scale``.
    """
    if disp.dim() != 4 or disp.shape[1] != 1 or disp.shape[-2:] != image.shape[-2:]:
        raise ValueError(
            f"smoothness_loss: expected disp (B, 1, H, W) matching image {tuple(image.shape)}, "
            f"got {tuple(disp.shape)}"
        )
    d_dx = (disp[..., :, :-1] - disp[..., :, 1:]).abs()
    d_dy = (disp[..., :-1, :] - disp[..., 1:, :]).abs()
    w_x = torch.exp(-(image[..., :, :-1] - image[..., :, 1:]).abs().mean(1, keepdim=True))
    w_y = torch.exp(-(image[..., :-1, :] - image[..., 1:, :]).abs().mean(1, keepdim=True))
    return (d_dx * w_x).mean() + (d_dy * w_y).mean()


def lr_consistency_loss(
    disp_left: Tensor, disp_right: Tensor, padding_mode: PaddingMode = "border"
) -> Tensor:
    """Left-right disparity consistency ``mean|d_l - warp(d_r, -d_l)| + mean|d_r - warp(d_l, d_r)|``.

    Each view's disparity should equal the other view's disparity seen through it.
    """
    right_to_left = warp(disp_right, -disp_left, padding_mode)
    left_to_right = warp(disp_left, disp_right, padding_mode)
    return (disp_left - right_to_left).abs().mean() + (disp_right - left_to_right).abs().mean()


def scale_pyramid(image: Tensor, num_scales: int = 4) -> list[Tensor]:
    """``[image, image/2, ..., image/2**(num_scales-1)]`` by area (average) downsampling.

    Scale s is (H // 2**s, W // 2**s), the size of the network's disparity at that scale.
    """
    h, w = image.shape[-2:]
    pyramid = [image]
    for s in range(1, num_scales):
        size = (h >> s, w >> s)
        if min(size) < 1:
            raise ValueError(f"scale_pyramid: {h}x{w} image has no scale {s} (would be {size})")
        pyramid.append(F.interpolate(image, size=size, mode="area"))
    return pyramid


# ----------------------------------------------------------------------------- module


class MonodepthLoss(nn.Module):
    """Monodepth's multi-scale stereo loss (appearance + smoothness + left-right consistency).

    Holds :class:`LearnedLevelWeights` as ``level_weights`` when ``msssim_cfg.weights ==
    "learned"`` (else ``None``), so those parameters reach the optimiser via ``.parameters()``.
    """

    def __init__(
        self,
        loss_cfg: LossConfig,
        appearance: Literal["ssim", "msssim"],
        ssim_cfg: SSIMConfig,
        msssim_cfg: MSSSIMConfig,
    ) -> None:
        super().__init__()
        if appearance not in ("ssim", "msssim"):
            raise ValueError(f"MonodepthLoss: appearance must be 'ssim' or 'msssim', got {appearance!r}")
        self.loss_cfg, self.appearance = loss_cfg, appearance
        self.ssim_cfg, self.msssim_cfg = ssim_cfg, msssim_cfg
        learned = appearance == "msssim" and msssim_cfg.weights == "learned"
        self.level_weights = LearnedLevelWeights(msssim_cfg.levels) if learned else None

    def forward(self, disps: Sequence[Tensor], left: Tensor, right: Tensor) -> dict[str, Tensor]:
        """Loss terms for one batch.

        Args:
            disps: per scale (fine -> coarse), (B, 2, H/2**s, W/2**s); channel 0 is the left
                disparity, 1 the right, as fractions of width.
            left, right: the (B, 3, H, W) stereo pair.

        Returns:
            ``"appearance"``, ``"smoothness"`` (sum of per-scale terms / 2**s) and
            ``"lr_consistency"``, each summed over scales and both views, and ``"total"`` =
            appearance + smoothness_weight·smoothness + lr_weight·lr_consistency.
        """
        cfg = self.loss_cfg
        # Built per call (cheap) rather than stored, so copies of this module never keep a
        # closure over another copy's level weights.
        similarity = make_pyramid_similarity(
            self.appearance, self.ssim_cfg, self.msssim_cfg, self.level_weights
        )
        # Both views in one batch (left then right): half the warp, pooling and similarity calls,
        # whose cost at the small scales is mostly per-call overhead.
        batch = left.shape[0]
        targets = scale_pyramid(torch.cat((left, right)), len(disps))
        estimates = []
        smoothness = lr = left.new_zeros(())
        for s, (disp, target) in enumerate(zip(disps, targets)):
            if disp.dim() != 4 or disp.shape[1] != 2 or disp.shape[-2:] != target.shape[-2:]:
                raise ValueError(
                    f"MonodepthLoss: scale {s} disparity must be (B, 2, {target.shape[-2]}, "
                    f"{target.shape[-1]}), got {tuple(disp.shape)}"
                )
            left_s, right_s = target[:batch], target[batch:]
            disp_left, disp_right = disp[:, :1], disp[:, 1:]
            # Left from right with -d_left, right from left with +d_right.
            sources, shifts = torch.cat((right_s, left_s)), torch.cat((-disp_left, disp_right))
            estimates.append(warp(sources, shifts, cfg.padding_mode))
            smooth_s = smoothness_loss(disp_left, left_s) + smoothness_loss(disp_right, right_s)
            smoothness = smoothness + smooth_s / 2**s
            lr = lr + lr_consistency_loss(disp_left, disp_right, cfg.padding_mode)
        appearance = left.new_zeros(())
        for sim, estimate, target in zip(similarity(estimates, targets), estimates, targets):
            # Each view's term is a mean over equally many values, so their sum is 2x the joint mean.
            appearance = appearance + 2 * _appearance_loss(sim, estimate, target, cfg.alpha)
        total = appearance + cfg.smoothness_weight * smoothness + cfg.lr_weight * lr
        return {"total": total, "appearance": appearance, "smoothness": smoothness, "lr_consistency": lr}
