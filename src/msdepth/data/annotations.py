"""The project's own hand-drawn ROI annotations on real frames, e.g. ``data_lists/kitti2015_rois.csv``.

The boxes are in the pipeline's ROI format (:func:`msdepth.data.kitti.read_rois`: image, class,
x0, y0, x1, y1; x1/y1 exclusive), so the ROI suite reads them as they are. The reader here also
checks them against the image size. :func:`gt_density` says how much ground truth each box holds.
The module is outside the pipeline's stages, so it can change without making ``dvc.lock`` stale.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from msdepth.data import kitti
from msdepth.errors import DataError

KITTI2015_SIZE = (375, 1242)  # (height, width) of a KITTI 2015 training frame at full resolution


def read_annotation(path: Path | str, size: tuple[int, int] = KITTI2015_SIZE) -> pd.DataFrame:
    """Hand-drawn ROI boxes (columns image, class, x0, y0, x1, y1; x1/y1 exclusive) on images of
    ``size`` = (height, width), e.g. ``data_lists/kitti2015_rois.csv``.

    The format, integer coordinates and classes are :func:`msdepth.data.kitti.read_rois`'s; a box
    must also lie inside the image. Any bad row raises one DataError line naming the file and its
    CSV line number.
    """
    boxes = kitti.read_rois(path)  # columns, integers, non-empty boxes, known classes
    h, w = size
    for i, row in enumerate(boxes.itertuples(index=False), start=2):  # CSV line numbers (header 1)
        if row.x1 > w or row.y1 > h:
            raise DataError(
                f"{path}: row {i}: box ({row.x0}, {row.y0}, {row.x1}, {row.y1}) lies outside the "
                f"{w}x{h} image (x1 <= {w} and y1 <= {h}, exclusive)"
            )
    return boxes


def gt_density(boxes: pd.DataFrame, gt: dict[str, np.ndarray]) -> np.ndarray:
    """Per box, the share of its pixels with ground truth (``gt[image] > 0``; NaN counts as none).

    ``gt`` maps each box's image to its GT map (disparity or depth). The share is over the whole
    box, as the ROI suite scores the whole box.
    """
    out = np.empty(len(boxes), dtype=np.float64)
    for k, box in enumerate(boxes.itertuples(index=False)):
        if box.image not in gt:
            raise DataError(f"box {k} names image {box.image!r}, which has no GT here")
        out[k] = float((gt[box.image][box.y0 : box.y1, box.x0 : box.x1] > 0).mean())
    return out
