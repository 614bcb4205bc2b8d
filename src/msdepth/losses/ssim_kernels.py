"""The fast CPU/GPU kernels behind :func:`msdepth.losses.ssim.ssim` and
:func:`msdepth.losses.ssim.ms_ssim`.

Private: the loss module defines what is computed; this module computes the same values (and
gradients) with less memory traffic: fused window moments with a hand-written backward
(:class:`_SSIMTerms`), O(log k) box sums, cache-sized chunks, a 2x2 mean with its own backward
(:class:`_Halve`) and a scheduler that batches same-sized MS-SSIM levels of a scale pyramid
(:func:`ms_ssim_levels`). :mod:`msdepth.losses.ssim` holds the plain autograd formula they are tested
against (``implementation="reference"``); the measurements behind each choice are in
``benchmarks/loss.py`` and benchmarks/README.md.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Literal, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

Window = Literal["box", "gaussian"]

C1 = 0.01**2  # (K1 · data_range)², data_range = 1
C2 = 0.03**2

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

        Separable sums of shifted views (box: :func:`_box_sum_1d`, Gaussian:
        :func:`_symmetric_sum_1d`): faster than depthwise ``conv2d`` or ``avg_pool2d`` on CPU
        (``benchmarks/loss.py``), and plain elementwise arithmetic that autocast never lowers.
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


# Image planes per chunk of :class:`_SSIMTerms`: the padded moment maps hold about this many
# elements, so that their ~10 passes stay in cache on the CPU (2^19, 2 MiB in fp32); on other
# devices (CUDA) every plane at once up to 1 GiB, since each chunk costs ~70 kernel launches.
# Measurements: benchmarks/loss.py.
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
            for d_mu, (_, _, mu_own, mu_other, _) in zip(d_mu_maps, wanted, strict=True):
                # dL/dμx = -(dL/dE[xy]·μy + 2·dL/dE[x² + y²]·μx), and symmetrically for μy; the
                # luminance adds 2·g·(μy - luminance·μx) / (μx² + μy² + C1).
                torch.mul(d_xy, mu_other, out=d_mu).addcmul_(d_sq, mu_own, value=2).neg_()
                if g_lum is not None:
                    d_mu.addcmul_(g_lum, torch.addcmul(mu_other, lum, mu_own, value=-1))
            g_xy, g_sq, *g_mu = win.sum(buf[:n]).split(1, dim=1)
            for g_mu_i, (own, other, _, _, grad) in zip(g_mu, wanted, strict=True):
                torch.addcmul(g_mu_i, own, g_sq, value=2, out=grad[start:stop]).addcmul_(other, g_xy)
        return _unplane(grad_x, x), _unplane(grad_y, y), None, None


def _unplane(planes: Tensor | None, like: Tensor) -> Tensor | None:
    return None if planes is None else planes.view(like.shape)


def ssim_terms(
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


def downsample(x: Tensor) -> Tensor:
    """pytorch-msssim's downsampling between MS-SSIM levels: 2x2 average pooling, padding = size % 2.

    Odd sizes pad 1 px and (default ``count_include_pad``) halve that edge row/column; the same
    for x and y, so x == y stays 1. Even sizes (every level of the training pyramid) take
    :class:`_Halve`, the same means without ``avg_pool2d``'s overhead.
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


def ms_ssim_levels(
    xs: Sequence[Tensor],
    ys: Sequence[Tensor],
    kernel_size: int,
    levels: int,
    window: Window,
    sigma: float,
    padding: Literal["same", "valid"],
) -> Tensor:
    """Per-level MS-SSIM values of every pair ``(xs[i], ys[i])``, as (len(xs), levels, B, C):
    the mean ``cs`` of levels 0 .. levels - 2 and the mean SSIM of the last level (inputs checked
    by the caller).

    Pair i starts i rounds late, so that in a scale pyramid (pair i half the size of pair i - 1)
    its level l lines up with level i + l of pair 0, and each round sends all same-sized levels
    through the SSIM terms and the downsampling as one batch: fewer calls, whose cost at the
    coarse levels is mostly overhead. Per image the arithmetic is that of one pair at a time;
    pairs of other sizes work too (a round then makes one call per distinct size).
    """
    n, batch = len(xs), xs[0].shape[0]
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
                cs, full = ssim_terms(x, y, kernel_size, window, sigma, padding, luminance=True)
                values[pairs[0]].append(full.flatten(2).mean(-1)[:batch])
            else:
                cs = ssim_terms(x, y, kernel_size, window, sigma, padding, luminance=False)
            continuing = pairs[1:] if ends else pairs
            if not continuing:
                continue
            skip = (len(pairs) - len(continuing)) * batch
            cs_means = cs.flatten(2).mean(-1)[skip:].split(batch)
            x, y = downsample(x[skip:]).split(batch), downsample(y[skip:]).split(batch)
            for j, i in enumerate(continuing):
                values[i].append(cs_means[j])
                active[i] = x[j], y[j]
        active.pop(round_ - levels + 1, None)
    return torch.stack([v for pair in values for v in pair]).unflatten(0, (n, levels))
