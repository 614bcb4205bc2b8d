"""OpenCV's semi-global block matcher (``cv2.StereoSGBM``), the classic reference beside the loss's
own matching cost (:mod:`msdepth.optimum.cost_volume` + :mod:`msdepth.optimum.sgm`).

Settings: ``MODE_SGBM_3WAY`` (8-direction-like aggregation in three passes), ``numDisparities`` =
D rounded up to a multiple of 16 (OpenCV's requirement; D defaults to the network heads' 0.3·W, as
the cost volume's), ``blockSize`` 5 and OpenCV's recommended penalties for 3 channels,
``P1 = 8·3·5²`` and ``P2 = 32·3·5²``. The remaining ones are those of OpenCV's stereo_match sample:
``preFilterCap`` 63, ``uniquenessRatio`` 10, ``speckleWindowSize`` 100 px with ``speckleRange``
32 (1/16 px units: 2 px), and a left-right check of ``disp12MaxDiff`` 1 px, as :mod:`msdepth.optimum.sgm`'s.

SGBM gives no disparity to its leftmost ``numDisparities`` columns (a third of a KITTI frame at
0.3·W); both views are therefore padded on the left by that many copies of their edge column and
the result cropped, so every pixel can match within the right image (disparities past its edge
read the edge column, as the loss's reconstruction and the cost volume do). On the two KITTI 2015
frames of ../shared/real-samples this takes D1 from 32 % / 21 % to 10 % / 7 % at D = 0.3·W.
The pixels OpenCV still marks invalid (occlusions, failed checks, speckles) are filled as
:func:`msdepth.optimum.sgm.fill_holes` does: the lower neighbour along the row.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from msdepth.optimum.cost_volume import default_max_disparity
from msdepth.optimum.sgm import fill_holes

BLOCK_SIZE = 5
CHANNELS = 3
P1 = 8 * CHANNELS * BLOCK_SIZE**2
P2 = 32 * CHANNELS * BLOCK_SIZE**2
PRE_FILTER_CAP = 63
UNIQUENESS_RATIO = 10
SPECKLE_WINDOW = 100
SPECKLE_RANGE = 32
LR_MAX_DIFF = 1
SUBPIXEL = 16  # OpenCV's disparities are fixed point, 1/16 px


def _num_disparities(max_disparity: int) -> int:
    """OpenCV's ``numDisparities`` for disparities up to ``max_disparity``: a multiple of 16, at least 16."""
    return max(16, 16 * math.ceil(max_disparity / 16))


def sgbm_disparity(
    left: np.ndarray, right: np.ndarray, max_disparity: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The left view's disparity (px, float32, holes filled) of a rectified uint8 RGB pair
    ``(H, W, 3)`` by OpenCV's SGBM, and where OpenCV found one (before filling), both (H, W)."""
    if left.shape != right.shape or left.ndim != 3 or left.shape[-1] != CHANNELS or left.dtype != np.uint8:
        raise ValueError(f"SGBM: expected two uint8 (H, W, 3) images, got {left.shape} and {right.shape}")
    top = default_max_disparity(left.shape[1]) if max_disparity is None else int(max_disparity)
    count = _num_disparities(top)
    matcher = cv2.StereoSGBM_create(
        minDisparity=0,
        numDisparities=count,
        blockSize=BLOCK_SIZE,
        P1=P1,
        P2=P2,
        disp12MaxDiff=LR_MAX_DIFF,
        preFilterCap=PRE_FILTER_CAP,
        uniquenessRatio=UNIQUENESS_RATIO,
        speckleWindowSize=SPECKLE_WINDOW,
        speckleRange=SPECKLE_RANGE,
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )
    padded = [cv2.copyMakeBorder(image, 0, 0, count, 0, cv2.BORDER_REPLICATE) for image in (left, right)]
    raw = matcher.compute(*padded)[:, count:]
    valid = raw >= 0  # invalid: (minDisparity - 1)·16
    disparity = raw.astype(np.float32) / SUBPIXEL
    return fill_holes(disparity, valid), valid
