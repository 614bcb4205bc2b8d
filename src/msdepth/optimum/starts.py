"""Starts for the losses' own optimum (issue #38): the disparity maps, left and right view, that the
solver's refinement (:func:`msdepth.optimum.solver.optimise` with ``start``) begins from.

``constant``: ``optimum.init_disparity`` everywhere (the coarse-to-fine solver's own start, here for
completeness: the solver does not need a map for it). ``cost``: semi-global matching
(:func:`msdepth.optimum.sgm.sgm`, its defaults) over the variant's own cost volume
(:mod:`msdepth.optimum.cost_volume`, D = 0.3·W). ``sgbm``: OpenCV's SGBM
(:func:`msdepth.optimum.sgbm.sgbm_disparity`).

Both matchers run on the pair at the frame's own size (:func:`capped_size`: its largest halving
within ``optimum.max_width``), whatever the working size: a disparity as a fraction of the width
does not depend on the size, so one match serves every working size and the refinement's result
can be compared across sizes from the same start. The map is then area-resampled to the working
size (the images' own filter).

The right view's disparity is derived from the left one by warping (:func:`_right_from_left`), not
by a second, right-view match: left pixel x at disparity d is right pixel x − d; where several left
pixels land on one right pixel the largest disparity (the nearest surface) wins, and right pixels
no left pixel lands on (seen only from the right: the right of near objects) are filled with the
lower neighbour along the row, as the matchers fill their own holes. The pair is then left-right
consistent wherever both views see the surface, which is what the objective's consistency term
asks.
"""

from __future__ import annotations

import cv2
import numpy as np

from msdepth.config.params import OPTIMUM_STARTS, Params
from msdepth.data.pairs import resize, to_tensor
from msdepth.errors import ConfigError
from msdepth.networks.common import MAX_DISPARITY
from msdepth.optimum.cost_volume import cost_volume, matching_cost
from msdepth.optimum.sgbm import sgbm_disparity
from msdepth.optimum.sgm import fill_holes, sgm

# px: the shortest side a halving by optimum.max_width keeps (the solver's coarse levels' own floor).
MIN_CAPPED_SIDE = 24


def capped_size(size: tuple[int, int], max_width: int) -> tuple[int, int]:
    """``(height, width)`` halved (rounding down, as the solver's levels) while wider than
    ``max_width`` and both halves keep :data:`MIN_CAPPED_SIDE` px; ``size`` itself when
    ``max_width`` is 0 (no cap)."""
    height, width = size
    while max_width and width > max_width and min(height, width) // 2 >= MIN_CAPPED_SIDE:
        height, width = height // 2, width // 2
    return height, width


def matched_disparity(
    left: np.ndarray, right: np.ndarray, params: Params, variant: str, start: str
) -> np.ndarray:
    """The left view's disparity (px, float32, (H, W), holes filled) of a uint8 RGB pair at its own
    size by the ``cost`` (SGM on ``variant``'s cost volume) or ``sgbm`` matcher."""
    if start == "sgbm":
        return sgbm_disparity(left, right)[0]
    if start == "cost":
        volume = cost_volume(to_tensor(left), to_tensor(right), matching_cost(params, variant))
        return sgm(volume)[0]
    raise ConfigError(f"optimum.start: {start!r} is not a matcher; one of {list(OPTIMUM_STARTS[1:])}")


def _right_from_left(left_px: np.ndarray) -> np.ndarray:
    """The right view's disparity (px, float32, (H, W)) of a left-view disparity map (px), by
    forward warping: left pixel x lands on right pixel round(x − d), the largest disparity wins,
    and the right pixels none lands on take the lower neighbour along the row."""
    left_px = np.asarray(left_px, dtype=np.float32)
    height, width = left_px.shape
    rows, columns = np.indices((height, width))
    target = np.rint(columns - left_px).astype(np.int64)
    inside = (target >= 0) & (target < width)
    out = np.full((height, width), -1.0, dtype=np.float32)
    np.maximum.at(out, (rows[inside], target[inside]), left_px[inside])
    return fill_holes(out, out >= 0)


def start_disparity(
    left: np.ndarray,
    right: np.ndarray,
    params: Params,
    variant: str,
    start: str,
    size: tuple[int, int] | None = None,
) -> np.ndarray:
    """The start (2, h, w) float32: left and right disparity as fractions of the width, in
    [0, 0.3], of a uint8 RGB pair (H, W, 3) at the working ``size`` (default: the pair's own).

    Matched at the pair's own size capped by ``optimum.max_width`` (:func:`capped_size`; the pair
    area-resized to it) and area-resampled to ``size``; the right channel warped from the left
    (:func:`_right_from_left`). ``constant``: ``optimum.init_disparity`` in both.
    """
    if start not in OPTIMUM_STARTS:
        raise ConfigError(f"optimum.start: unknown start {start!r}; one of {list(OPTIMUM_STARTS)}")
    height, width = size or left.shape[:2]
    if start == "constant":
        return np.full((2, height, width), params.optimum.init_disparity, dtype=np.float32)
    match = capped_size(left.shape[:2], params.optimum.max_width)
    left, right = (resize(image, *match) for image in (left, right))
    return both_views(matched_disparity(left, right, params, variant, start), (height, width))


def both_views(left_px: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """A matched start (2, h, w) float32, fractions of the width in [0, 0.3], from the left view's
    disparity (px, (H, W), at the pair's own size): the right view warped from it
    (:func:`_right_from_left`), both area-resampled to ``size``."""
    height, width = size
    both = np.stack((left_px, _right_from_left(left_px)), axis=-1) / left_px.shape[1]
    if both.shape[:2] != (height, width):
        both = cv2.resize(both, (width, height), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(np.clip(both, 0.0, MAX_DISPARITY).transpose(2, 0, 1), dtype=np.float32)
