"""Semi-global matching (Hirschmüller, PAMI 2008) on a cost volume, and the classic stereo
post-processing around it: a global disparity from any ``(H, W, D + 1)`` matching cost, e.g. a loss
variant's own (:mod:`msdepth.optimum.cost_volume`).

Aggregation. Along each of 4 (horizontal, vertical) or 8 (and diagonal) paths r, every pixel p
accumulates

    L_r(p, d) = C(p, d) + min(L_r(p-r, d), L_r(p-r, d±1) + P1, min_k L_r(p-r, k) + P2) - min_k L_r(p-r, k)

(P1: a change of one pixel, e.g. a slanted surface; P2: any larger jump, a depth edge), and the
aggregated cost is ``S = Σ_r L_r``. A path starts at the image's edge with ``L_r = C``. Each path is
one loop along its direction, vectorised over a whole row (or column) and all disparities.

Penalties in the cost's own units: ``P = p · s`` with ``s`` the median over pixels of
``mean_d C - min_d C`` (:func:`_cost_scale`), how far a typical wrong disparity's cost lies above the
best; so one ``p1``, ``p2`` serve costs of any range (an SSIM term, an MS-SSIM term, an L1). The
defaults, ``p1 = 0.25`` and ``p2 = 4`` (P2 = 16·P1; OpenCV's SGBM uses 4·P1 on its block costs),
were chosen on the two KITTI 2015 frames of ../shared/real-samples with the SSIM cost at
D = 0.3·W: D1 10.2 % and 7.8 %; the 14 other pairs tried (p1 0.1–1, p2 0.4–16) gave 10.8–37 % and
8.0–32 %, SGBM 10.3 % and 6.8 %. SGM runs on the volume in int16 steps (:func:`_quantise`), as
OpenCV's does; its D1 there is that of float32 to 0.05 points.

Disparity: winner-take-all on S, refined to sub-pixel by the parabola through the minimum and
its two neighbours. Left-right check: the right view's disparity comes from the same S
re-indexed (right pixel x matches left pixel x + d, so ``S_R(x, d) = S(x + d, d)``), and a left
pixel whose match's right disparity differs by more than ``lr_tolerance`` px (or whose match falls
outside the right image) is invalid. Holes are filled per row from the nearest valid pixels on
either side, taking the lower disparity (the farther surface: occlusions are background), as
classic stereo pipelines (OpenCV's, KITTI's devkit) do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

# (dy, dx) per path: the step from a pixel's predecessor to the pixel.
PATHS_4 = ((0, 1), (0, -1), (1, 0), (-1, 0))
PATHS_8 = PATHS_4 + ((1, 1), (1, -1), (-1, 1), (-1, -1))
ROWS_PER_CHUNK = 16  # rows of the right view's re-indexed volume held at once
# SGM runs on int16 costs, as OpenCV's does: half the memory traffic of float32 and twice the SIMD
# lanes (about 2x faster). A _cost_scale is UNITS integer steps, fine beside the penalties (16 and
# more steps); costs are capped so that 8 paths' sums stay within int16 (L_r <= C + P2).
UNITS = 64
INT16_MAX = 32767


@dataclass(frozen=True)
class SGMConfig:
    """Semi-global matching's settings: path count (4 or 8), penalties as multiples of
    :func:`_cost_scale`, and the left-right check's tolerance (px)."""

    paths: int = 8
    p1: float = 0.25
    p2: float = 4.0
    lr_tolerance: float = 1.0

    def __post_init__(self) -> None:
        if self.paths not in (4, 8):
            raise ValueError(f"SGM: paths must be 4 or 8, got {self.paths}")
        if not 0 <= self.p1 <= self.p2:
            raise ValueError(f"SGM: need 0 <= p1 <= p2, got p1={self.p1}, p2={self.p2}")


def _cost_scale(volume: Tensor) -> float:
    """The median over pixels of ``mean_d C - min_d C`` of an (H, W, D + 1) volume (1 if 0)."""
    spread = volume.mean(-1) - volume.amin(-1)
    scale = float(spread.median())
    return scale if scale > 0 else 1.0


def _path_step(cost: Tensor, previous: Tensor, p1: float, p2: float, out: Tensor | None = None) -> Tensor:
    """``L_r`` of a slice of pixels (..., D + 1) given their predecessors' ``L_r`` (into ``out``)."""
    low = previous.amin(-1, keepdim=True)
    best = torch.minimum(previous, low + p2, out=out)
    if previous.shape[-1] > 1:
        below, above = best[..., 1:], best[..., :-1]
        torch.minimum(below, previous[..., :-1] + p1, out=below)
        torch.minimum(above, previous[..., 1:] + p1, out=above)
    return best.sub_(low).add_(cost)


def _walk_rows(volume: Tensor, total: Tensor, p1: float, p2: float, dy: int, dx: int) -> None:
    """Add one path walking down (dy = 1) or up (dy = -1) the rows, also sideways by ``dx``.

    Two buffers of W + 1 pixels alternate as this row's and the previous row's ``L_r``; their extra
    pixel, always 0 (no predecessor: ``L_r = C``), sits where a diagonal path enters the row, so a
    row's predecessors are a view of the other buffer, shifted by ``dx``.
    """
    height, width = volume.shape[:2]
    buffers = [volume.new_zeros(width + 1, volume.shape[-1]) for _ in range(2)]
    # Where the row's own L_r goes in a buffer, and where its predecessors are read from.
    own = slice(1, None) if dx > 0 else slice(0, width)
    read = {1: slice(0, width), -1: slice(1, None), 0: own}[dx]
    for i, y in enumerate(range(height) if dy > 0 else range(height - 1, -1, -1)):
        current, previous = buffers[i % 2], buffers[1 - i % 2]
        step = _path_step(volume[y], previous[read], p1, p2, out=current[own])
        total[y] += step


def _walk_columns(volume: Tensor, total: Tensor, p1: float, p2: float, dx: int) -> None:
    """Add one path walking right (dx = 1) or left (dx = -1) along the rows."""
    width = volume.shape[1]
    buffers = [torch.zeros_like(volume[:, 0]) for _ in range(2)]
    for i, x in enumerate(range(width) if dx > 0 else range(width - 1, -1, -1)):
        step = _path_step(volume[:, x], buffers[1 - i % 2], p1, p2, out=buffers[i % 2])
        total[:, x] += step


def _aggregate(volume: Tensor, p1: float, p2: float, paths: int = 8) -> Tensor:
    """``S = Σ_r L_r`` over 4 or 8 paths of an (H, W, D + 1) volume (float, or int16 steps with
    integer penalties: :func:`_quantise`), penalties in its units."""
    if volume.dim() != 3:
        raise ValueError(f"SGM: expected an (H, W, D + 1) volume, got shape {tuple(volume.shape)}")
    if paths not in (4, 8):
        raise ValueError(f"SGM: paths must be 4 or 8, got {paths}")
    total = torch.zeros_like(volume)
    with torch.no_grad():
        for dy, dx in PATHS_8 if paths == 8 else PATHS_4:
            if dy:
                _walk_rows(volume, total, p1, p2, dy, dx)
            else:
                _walk_columns(volume, total, p1, p2, dx)
    return total


def _subpixel(aggregated: Tensor, best: Tensor) -> Tensor:
    """(H, W) float disparity: the integer minimum ``best`` moved to the vertex of the parabola
    through its cost and its two neighbours' (unchanged at 0 and D, or where the cost is flat)."""
    top = aggregated.shape[-1] - 1
    index = best.clamp(1, max(top - 1, 1)).unsqueeze(-1)
    c0 = aggregated.gather(-1, index - 1)[..., 0].double()
    c1 = aggregated.gather(-1, index)[..., 0].double()
    c2 = aggregated.gather(-1, (index + 1).clamp(max=top))[..., 0].double()
    curvature = c0 - 2 * c1 + c2
    inner = (best > 0) & (best < top) & (curvature > 0)
    offset = torch.where(inner, (c0 - c2) / (2 * curvature.clamp(min=1e-12)), torch.zeros_like(c1))
    return best.float() + offset.clamp(-0.5, 0.5).float()


def _right_disparity(aggregated: Tensor) -> Tensor:
    """(H, W) long: the right view's winner-take-all disparity from the left view's volume,
    ``argmin_d S(y, x + d, d)`` (disparities reaching past the left image's edge left out).

    A block of rows is copied into a buffer whose rows run on for n = D + 1 pixels of ``inf``: there
    ``S(y, x + d, d)`` lies at ``y·(W + n)·n + x·n + d·(n + 1)``, a strided view, and the
    disparities past the edge read ``inf``.
    """
    height, width, count = aggregated.shape
    out = torch.empty(height, width, dtype=torch.long)
    high = torch.inf if aggregated.is_floating_point() else torch.iinfo(aggregated.dtype).max
    buffer = aggregated.new_full((ROWS_PER_CHUNK, width + count, count), high)
    for top in range(0, height, ROWS_PER_CHUNK):
        block = aggregated[top : top + ROWS_PER_CHUNK]
        rows = block.shape[0]
        buffer[:rows, :width].copy_(block)
        view = buffer.as_strided((rows, width, count), ((width + count) * count, count, count + 1))
        out[top : top + rows] = view.argmin(-1)
    return out


def _lr_valid(left: Tensor, right: Tensor, tolerance: float = 1.0) -> Tensor:
    """(H, W) bool: left disparities (float px) whose match ``x - d`` (rounded) is in the right
    image and has a right disparity within ``tolerance`` px."""
    width = left.shape[-1]
    match = (torch.arange(width, dtype=left.dtype) - left).round().long()
    inside = match >= 0
    seen = right.gather(-1, match.clamp(min=0)).to(left.dtype)
    return inside & ((left - seen).abs() <= tolerance)


def fill_holes(disparity: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``disparity`` (H, W) with every invalid pixel set to the lower of the nearest valid
    disparities left and right of it in its row (the one side there is at a row's end; 0 in a row
    with none)."""
    disparity, valid = np.asarray(disparity, dtype=np.float32), np.asarray(valid, dtype=bool)
    width = disparity.shape[-1]
    columns = np.arange(width)
    before = np.maximum.accumulate(np.where(valid, columns, -1), axis=-1)
    after = np.minimum.accumulate(np.where(valid, columns, width)[..., ::-1], axis=-1)[..., ::-1]
    left = np.where(before >= 0, np.take_along_axis(disparity, before.clip(0), -1), np.inf)
    right = np.where(after < width, np.take_along_axis(disparity, after.clip(max=width - 1), -1), np.inf)
    nearest = np.minimum(left, right)
    nearest[np.isinf(nearest)] = 0.0
    return np.where(valid, disparity, nearest).astype(np.float32)


def _quantise(volume: Tensor, scale: float, p2: float, paths: int) -> Tensor:
    """An (H, W, D + 1) volume as int16 steps of ``scale / UNITS`` above its minimum (SGM's result
    does not change with a constant added to the cost), capped so that ``paths`` paths' sums of
    ``L_r <= C + P2`` (P2 = ``p2`` steps) fit int16."""
    cap = INT16_MAX // paths - math.ceil(p2)
    if cap < UNITS:
        raise ValueError(f"SGM: p2 = {p2 / UNITS:g} cost scales leaves no int16 range for {paths} paths")
    low, factor = float(volume.min()), UNITS / scale
    steps = torch.empty(volume.shape, dtype=torch.int16)
    for top in range(0, volume.shape[0], ROWS_PER_CHUNK):  # by rows: no full-size float temporary
        block = volume[top : top + ROWS_PER_CHUNK]
        steps[top : top + ROWS_PER_CHUNK] = (block - low).mul_(factor).round_().clamp_(max=cap)
    return steps


def sgm(volume: Tensor, config: SGMConfig = SGMConfig()) -> tuple[np.ndarray, np.ndarray]:
    """Semi-global matching of an (H, W, D + 1) cost volume: the left view's disparity (px, float32,
    holes filled) and its validity before filling (the left-right check), both (H, W). Runs on the
    volume in int16 steps of ``_cost_scale / UNITS`` (:func:`_quantise`)."""
    p1, p2 = round(config.p1 * UNITS), round(config.p2 * UNITS)
    steps = _quantise(volume, _cost_scale(volume), p2, config.paths)
    aggregated = _aggregate(steps, p1, p2, config.paths)
    del steps
    best = aggregated.argmin(-1)
    left = _subpixel(aggregated, best)
    valid = _lr_valid(left, _right_disparity(aggregated), config.lr_tolerance)
    return fill_holes(left.numpy(), valid.numpy()), valid.numpy()
