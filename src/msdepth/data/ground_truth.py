"""Evaluation ground truth as depth in metres, whatever form a set stores it in.

One reader for every evaluation set (:func:`read_gt_depth`), so the suites see the same data
model for KITTI 2015 (disparity PNGs), the Eigen split (Velodyne scans projected with the day's
calibration) and the KITTI depth benchmark (depth PNGs). The index says which form a frame has.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..depth import disparity_to_depth
from ..errors import DataError
from . import kitti

# The index's ``gt_kind`` column: what its ``gt`` file holds.
GT_KINDS = {
    "disparity": "KITTI disparity PNG (uint16, pixels x 256); depth = focal * baseline / disparity",
    "depth": "KITTI depth-benchmark PNG (uint16, metres x 256)",
    "velodyne": "KITTI Velodyne scan (.bin), projected into camera 2 with the raw day's calibration",
}


def read_gt_depth(
    kind: str, path: str | os.PathLike, *, calib: str | os.PathLike = "", focal: float, baseline: float
) -> np.ndarray:
    """GT depth (m, float32, 0 = none) of one evaluation frame from its ``kind`` of file.

    ``calib``: the raw day folder (``raw/<date>/``) of a ``velodyne`` frame, whose
    ``calib_cam_to_cam.txt`` and ``calib_velo_to_cam.txt`` project the scan (:func:`kitti.velodyne_depth`).
    """
    if kind == "disparity":
        return disparity_to_depth(kitti.read_disparity(path), focal, baseline)
    if kind == "depth":
        return kitti.read_depth(path)
    if kind == "velodyne":
        if not calib:
            raise DataError(
                f"{path}: a Velodyne GT frame needs its raw day folder (the index's calib column)"
            )
        return kitti.velodyne_depth(path, kitti.read_raw_calib(Path(calib)))
    raise DataError(f"{path}: unknown GT kind {kind!r}; known: {sorted(GT_KINDS)}")
