"""The losses' own optimum: per stereo pair, the disparity maps that minimise a variant's training
objective, optimised directly, with no network (docs/optimum.md says what this measures).

The objective is training's :class:`msdepth.losses.monodepth.MonodepthLoss` of the variant (its appearance
term at the 4 scales, edge-aware smoothness and left-right consistency; alpha, lr_weight and the
warp's padding from ``params.loss``), with the optimum's own smoothness weight
(``optimum.smoothness_weight``). The free variables are a left and a right disparity map per
pair, fractions of the width in (0, 0.3) as the network's heads output them (``0.3·sigmoid``
of a logit, which Adam updates). The 4 scales the loss sees are the area-downsampled map
(:func:`disparity_pyramid`), the scales of the images.

Coarse to fine: from a constant start, ``optimum.iterations`` Adam steps on the pair shrunk by
``2**l`` for l = levels - 1 .. 0 (the same objective on smaller images), each level starting
from the coarser one's logits upsampled. The stopping rule is that fixed number of steps, the
same for every pair: a rule on the loss's change would make a pair's result depend on its batch
(docs/optimum.md has the measurement behind the default).

Cost curves (:func:`cost_curve`): a variant's appearance cost of the whole frame, exactly as
training computes it, with the disparity in a box scaled by ``s`` and the GT elsewhere; the
``s`` that minimises it and the width of its basin say where the loss "wants" that surface.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor
from tqdm import tqdm

from msdepth.config.params import OptimumConfig, Params
from msdepth.data.pairs import resize, to_tensor
from msdepth.errors import ConfigError, DataError
from msdepth.losses.monodepth import MonodepthLoss, reconstruct, scale_pyramid
from msdepth.losses.objective import build_loss
from msdepth.networks.common import MAX_DISPARITY
from msdepth.networks.device import resolve_device
from msdepth.optimum.starts import capped_size, start_disparity

NUM_SCALES = 4  # the network's disparity scales (1, 1/2, 1/4, 1/8), all of which training's loss sees
# px: the shortest side of a coarse level; its coarsest training scale (1/8) keeps 3 px, SSIM's window.
MIN_LEVEL_SIDE = 24
COST_SCALES = np.geomspace(0.5, 2.0, 25)  # the cost curves' s grid: log-spaced, s = 1 in the middle
BASIN_TOLERANCE = 0.05  # the basin: s whose cost rises less than this share of the curve's range
# s_min: the s nearest 1 among those whose cost is within this share of the lowest cost. Rounding
# moves a mean cost by <= 5e-8 of it (1 against 2 threads, the default set's 8 frames); the two
# lowest points of a default run's curves are >= 4.1e-6 of the cost apart (MS-SSIM's 2 signs).
# 1e-6 is 20x the one and 1/4 of the other: ties of exact arithmetic become ties, real
# differences stay differences.
S_MIN_TOLERANCE = 1e-6
# A matched start's disparity is kept this share of the heads' range (0.3) off its ends: the
# sigmoid's gradient vanishes there (1e-3: 0.37 px at 1242 px, beyond the 80 m cap).
START_MARGIN = 1e-3


def objective(params: Params, variant: str, smoothness_weight: float | None = None) -> MonodepthLoss:
    """Training's loss of ``variant`` (:func:`msdepth.losses.objective.build_loss`) with the optimum's
    smoothness weight (default ``optimum.smoothness_weight``); any registered variant, trained or
    not. Its own parameters (learned MS-SSIM level weights) stay at their initial values."""
    if variant not in params.appearance:
        raise ConfigError(f"optimum: unknown variant {variant!r}; registered: {sorted(params.appearance)}")
    weight = params.optimum.smoothness_weight if smoothness_weight is None else smoothness_weight
    loss = dataclasses.replace(params.loss, smoothness_weight=weight)
    variants = params.variants if variant in params.variants else (*params.variants, variant)
    criterion = build_loss(dataclasses.replace(params, loss=loss, variants=variants), variant)
    return criterion.requires_grad_(False)


def working_weight(params: Params, width: int, smoothness_weight: float | None = None) -> float:
    """The smoothness weight at a working ``width``: ``smoothness_weight`` (default
    ``optimum.smoothness_weight``), times ``width / optimum.smoothness_width`` when that is set.

    The edge-aware smoothness term is a mean over pixels of the disparity's step to the next
    pixel, a fraction of the width: at twice the width a surface's steps halve, and so does the
    term, while the appearance term stays; scaling the weight with the width keeps their balance
    (docs/optimum.md has the measurement)."""
    weight = params.optimum.smoothness_weight if smoothness_weight is None else smoothness_weight
    reference = params.optimum.smoothness_width
    return weight * width / reference if reference else weight


def disparity_pyramid(disp: Tensor) -> list[Tensor]:
    """A (B, 2, H, W) disparity map at the loss's 4 scales (fine -> coarse), area-downsampled as the
    images are, so scale s has the size of the image pyramid's scale s."""
    return scale_pyramid(disp, NUM_SCALES)


def level_sizes(height: int, width: int, levels: int) -> list[tuple[int, int]]:
    """The coarse-to-fine working sizes (coarsest first): up to ``levels`` halvings of
    ``height`` x ``width`` whose shortest side keeps :data:`MIN_LEVEL_SIDE` px (always the full size)."""
    sizes = [(height >> level, width >> level) for level in range(levels)]
    fitting = [size for size in sizes if min(size) >= MIN_LEVEL_SIDE] or sizes[:1]
    return fitting[::-1]


def _logit(disparity: float) -> float:
    return math.log(disparity / (MAX_DISPARITY - disparity))


def _start_logits(start: Tensor) -> Tensor:
    """The logits of a (B, 2, H, W) start disparity (fractions of width): ``logit(start / 0.3)``,
    the ratio clamped to [:data:`START_MARGIN`, 1 - :data:`START_MARGIN`] so that a start on the
    range's edge (a matcher's 0 in a row with no match) keeps a usable gradient."""
    ratio = (start / MAX_DISPARITY).clamp(START_MARGIN, 1 - START_MARGIN)
    return torch.log(ratio / (1 - ratio))


def optimise(
    left: Tensor,
    right: Tensor,
    criterion: MonodepthLoss,
    cfg: OptimumConfig,
    trace: list[list[float]] | None = None,
    start: Tensor | None = None,
    observe: Callable[[int, Tensor], None] | None = None,
) -> Tensor:
    """The optimum of a batch of pairs: (B, 2, H, W) disparities (left, right) as fractions of width.

    From a constant (``start`` None): ``optimum.iterations`` Adam steps at each of
    ``optimum.levels`` levels. From ``start`` (B, 2, H, W), a matched start
    (:mod:`msdepth.optimum.starts`): ``optimum.refine_iterations`` steps at each of the finest
    ``optimum.refine_levels`` levels, the coarsest one's logits those of the area-downsampled start.
    Both at ``optimum.learning_rate``.

    A ConfigError when the variant's term does not fit a level (e.g. a valid-padded SSIM window
    larger than the coarsest scale): fewer levels or a larger working size then.

    ``left``, ``right``: (B, 3, H, W) in [0, 1]. ``trace``, when given, gets each level's
    per-step loss (summed over the batch), for measuring the stopping rule; ``observe``, when given,
    is called after each step with its number in the level (from 1) and the disparity (B, 2, h, w),
    for scoring the steps. Deterministic on CPU.
    """
    batch, _, height, width = left.shape
    if start is None:
        sizes = level_sizes(height, width, cfg.levels)
        logits = left.new_full((batch, 2, *sizes[0]), _logit(cfg.init_disparity))
        steps = cfg.iterations
    else:
        if start.shape != (batch, 2, height, width):
            raise ValueError(f"optimum: a start of shape {tuple(start.shape)} for pairs {tuple(left.shape)}")
        sizes = level_sizes(height, width, cfg.refine_levels)
        logits = _start_logits(F.interpolate(start.to(left), size=sizes[0], mode="area"))
        steps = cfg.refine_iterations
    for size in sizes:
        logits = F.interpolate(logits, size=size, mode="bilinear", align_corners=False)
        # The objective on the pair at this level's size (area: the filter of the image pyramid).
        left_l, right_l = (F.interpolate(x, size=size, mode="area") for x in (left, right))
        logits = _descend(logits, left_l, right_l, criterion, steps, cfg.learning_rate, trace, observe)
    with torch.no_grad():
        return MAX_DISPARITY * torch.sigmoid(logits)


def _descend(
    logits: Tensor,
    left: Tensor,
    right: Tensor,
    criterion: MonodepthLoss,
    steps: int,
    learning_rate: float,
    trace: list[list[float]] | None = None,
    observe: Callable[[int, Tensor], None] | None = None,
) -> Tensor:
    """``steps`` Adam steps on ``logits`` (B, 2, h, w) of the objective on one level's pair (B, 3,
    h, w); the logits after them (detached). ``trace`` and ``observe``: :func:`optimise`'s."""
    batch = left.shape[0]
    size = tuple(left.shape[-2:])
    logits = logits.detach().requires_grad_(True)
    adam = torch.optim.Adam([logits], lr=learning_rate)
    losses = []
    for _ in range(steps):
        disp = MAX_DISPARITY * torch.sigmoid(logits)
        # x batch: each pair's gradient is that of its own loss, whatever its batch mates.
        try:
            loss = criterion(disparity_pyramid(disp), left, right)["total"] * batch
        except ValueError as exc:
            raise ConfigError(f"optimum: at the {size[0]}x{size[1]} level: {exc}") from None
        adam.zero_grad(set_to_none=True)
        loss.backward()
        adam.step()
        losses.append(loss.item())
        if observe is not None:
            with torch.no_grad():
                observe(len(losses), MAX_DISPARITY * torch.sigmoid(logits))
    if trace is not None:
        trace.append(losses)
    return logits.detach()


def working_size(
    cfg: OptimumConfig, image_shape: tuple[int, ...], size: tuple[int, int] | None = None
) -> tuple[int, int]:
    """``(height, width)`` to optimise at: ``size`` if given (the CLI's ``--height/--width``), else
    ``optimum.height``/``width`` when set, else the image's own (the pipeline: the render size)."""
    if size is not None:
        return size
    if cfg.height and cfg.width:
        return cfg.height, cfg.width
    return int(image_shape[0]), int(image_shape[1])


def optimum_disparities(
    pairs: Sequence[tuple[np.ndarray, np.ndarray]],
    params: Params,
    variant: str,
    smoothness_weight: float | None = None,
    size: tuple[int, int] | None = None,
    progress: bool = True,
    start: str | None = None,
) -> list[np.ndarray]:
    """The left optimum disparity (fraction of width, float32 at the working size) of every
    ``(left, right)`` uint8 RGB pair, ``optimum.batch_size`` pairs at a time.

    ``size``: the working size (default: :func:`working_size`). A working size wider than
    ``optimum.max_width`` is solved at its largest halving within it
    (:func:`msdepth.optimum.starts.capped_size`) and the result resized back bilinearly (a
    fraction of the width needs no rescaling). Pairs are area-resized to the size solved at, as
    training's input is; the smoothness weight is :func:`working_weight`'s at its width.
    Consecutive pairs of one size share a batch. ``start``: ``constant``,
    ``cost`` or ``sgbm`` (default ``optimum.start``; :func:`msdepth.optimum.starts.start_disparity`,
    matched at each pair's own size, capped alike). The matchers run on the CPU; the refinement on
    ``train.device`` (:func:`msdepth.networks.device.resolve_device`: ``cuda`` without one is a
    one-line error before any pair is matched).
    """
    cfg = params.optimum
    start = cfg.start if start is None else start
    device = resolve_device(params.train.device)
    criteria: dict[float, MonodepthLoss] = {}  # by working weight (one per width, if scaled)
    out: list[np.ndarray] = []
    with tqdm(total=len(pairs), desc=f"optimum {variant}", unit="pair", disable=not progress) as bar:
        first = 0
        while first < len(pairs):
            h, w = working_size(cfg, pairs[first][0].shape, size)
            stop = first + 1
            while (
                stop < len(pairs)
                and stop - first < cfg.batch_size
                and working_size(cfg, pairs[stop][0].shape, size) == (h, w)
            ):
                stop += 1
            chunk = pairs[first:stop]
            solved = capped_size((h, w), cfg.max_width)
            left = torch.stack([to_tensor(resize(a, *solved)) for a, _ in chunk])
            right = torch.stack([to_tensor(resize(b, *solved)) for _, b in chunk])
            weight = working_weight(params, solved[1], smoothness_weight)
            if weight not in criteria:
                criteria[weight] = objective(params, variant, weight).to(device)
            init = batch_start(chunk, params, variant, start, solved)
            init = None if init is None else init.to(device)
            disp = optimise(left.to(device), right.to(device), criteria[weight], cfg, start=init)
            if solved != (h, w):
                disp = F.interpolate(disp, size=(h, w), mode="bilinear", align_corners=False)
            out += [d[0].cpu().numpy().astype(np.float32) for d in disp]
            bar.update(len(chunk))
            first = stop
    return out


def batch_start(
    pairs: Sequence[tuple[np.ndarray, np.ndarray]],
    params: Params,
    variant: str,
    start: str,
    size: tuple[int, int],
) -> Tensor | None:
    """The (B, 2, h, w) start of a batch of uint8 pairs at the working ``size``
    (:func:`msdepth.optimum.starts.start_disparity`), or None for the constant start."""
    if start == "constant":
        return None
    maps = [start_disparity(left, right, params, variant, start, size) for left, right in pairs]
    return torch.from_numpy(np.stack(maps))


# ----------------------------------------------------------------------------- cost curves


def cost_curve(
    left: Tensor,
    right: Tensor,
    gt_disp_px: np.ndarray,
    box: tuple[int, int, int, int],
    criterion: MonodepthLoss,
    scales: Sequence[float] = tuple(COST_SCALES),
) -> np.ndarray:
    """The appearance cost of the left view (the term's sum over the 4 scales, as training computes
    it) per ``s`` in ``scales``, with the disparity ``gt × s`` inside ``box`` = (x0, y0, x1, y1),
    x1/y1 exclusive, and ``gt`` outside.

    ``left``, ``right``: (3, H, W) in [0, 1]; ``gt_disp_px``: (H, W) disparity in px (0 = at
    infinity, e.g. sky). The whole frame is compared: MS-SSIM's coarse levels see a small box's
    surroundings. Only the left view has GT, so only its reconstruction is scored.
    """
    height, width = left.shape[-2:]
    if gt_disp_px.shape != (height, width):
        raise ValueError(f"cost_curve: GT {gt_disp_px.shape} does not match the image {(height, width)}")
    x0, y0, x1, y1 = box
    inside = torch.zeros(1, 1, height, width, dtype=left.dtype)
    inside[..., y0:y1, x0:x1] = 1.0
    base = torch.from_numpy(np.asarray(gt_disp_px, dtype=np.float32) / width).view(1, 1, height, width)
    targets = scale_pyramid(torch.stack((left, right)), NUM_SCALES)
    costs = []
    with torch.no_grad():
        for s in scales:
            disps = disparity_pyramid(base * (1 + (s - 1) * inside))
            estimates = [
                reconstruct(t[:1], t[1:], d, d, criterion.loss_cfg.padding_mode)[:1]
                for t, d in zip(targets, disps, strict=True)
            ]
            terms = criterion.appearance(estimates, [t[:1] for t in targets])
            costs.append(float(sum(term.item() for term in terms)))
    return np.array(costs)


def minimum_index(scales: Sequence[float], costs: np.ndarray, tolerance: float = S_MIN_TOLERANCE) -> int:
    """The index of ``s_min``: among the grid points whose cost exceeds the lowest by at most
    ``tolerance`` of the lowest cost's magnitude, the one nearest s = 1 (in log s: 0.5 and 2 are
    equally far); of two equally near, the smaller s.

    Not a plain argmin: on a flat basin, points equal in exact arithmetic differ in their last
    bits, which depend on the thread count and the CPU's kernels; the tolerance makes them a tie
    and the tie has one answer.
    """
    scales, costs = np.asarray(scales, dtype=float), np.asarray(costs, dtype=float)
    if costs.shape != scales.shape or not costs.size or not np.isfinite(costs).all():
        raise DataError(f"cost curve: expected {scales.size} finite costs, got {costs.tolist()}")
    lowest = costs.min()
    near = np.flatnonzero(costs <= lowest + tolerance * abs(lowest))
    # Distances rounded: log(s) and log(1/s) of a geometric grid may differ in their last bit.
    distance = np.round(np.abs(np.log(scales[near])), 9)
    return int(near[np.lexsort((scales[near], distance))[0]])


def _curve_minimum(scales: Sequence[float], costs: np.ndarray) -> float:
    """``s_min``: the ``s`` of the lowest cost, rounding-proof (:func:`minimum_index`)."""
    return float(np.asarray(scales)[minimum_index(scales, costs)])


def basin(
    scales: Sequence[float], costs: np.ndarray, tolerance: float = BASIN_TOLERANCE
) -> tuple[float, float]:
    """``(s_low, s_high)``: the contiguous range of ``s`` around ``s_min`` (:func:`minimum_index`)
    whose cost exceeds the lowest by at most ``tolerance`` of the curve's range (max - min over
    the grid), and never by less than ``s_min``'s own tolerance.

    Relative to the range, not to the minimum's cost: a box changes a whole frame's cost by a
    small fraction, so 5 % of the cost itself would take in every ``s`` of the grid. Grown from
    ``s_min``, not from the argmin, so that the basin always holds ``s_min`` and moves with it only;
    a curve flat to within rounding is one basin.
    """
    scales, costs = np.asarray(scales, dtype=float), np.asarray(costs, dtype=float)
    best = minimum_index(scales, costs)
    lowest = costs.min()
    limit = lowest + max(tolerance * (costs.max() - lowest), S_MIN_TOLERANCE * abs(lowest))
    low = high = best
    while low > 0 and costs[low - 1] <= limit:
        low -= 1
    while high < len(costs) - 1 and costs[high + 1] <= limit:
        high += 1
    return float(scales[low]), float(scales[high])


def class_summary(
    curves: dict[str, list[np.ndarray]], scales: Sequence[float] = tuple(COST_SCALES)
) -> dict[str, dict[str, float]]:
    """Per ROI class, from its boxes' curves: the ``s`` minimising the mean curve, its basin and
    the basin's width as a ratio (``s_high / s_low``; 1 = only the minimum's grid point)."""
    out = {}
    for cls, rows in sorted(curves.items()):
        mean = np.mean(np.stack(rows), axis=0)
        low, high = basin(scales, mean)
        out[cls] = {
            "rois": len(rows),
            "s_min": _curve_minimum(scales, mean),
            "basin_low": low,
            "basin_high": high,
            "basin_ratio": high / low,
        }
    return out
