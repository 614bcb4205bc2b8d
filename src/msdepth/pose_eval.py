"""Monodepth2's pose evaluation: absolute trajectory error (ATE) over 5-frame snippets.

As Monodepth2's ``evaluate_pose.py``: the relative poses of consecutive frames (each mapping a
frame's camera points to the next frame's camera, :func:`msdepth.pose.relative_pose` with offset
+1) are chained over a snippet of ``track_length`` frames into camera positions, the first
frame at the origin; the predicted positions are shifted so the first ones coincide, scaled by
the least-squares factor onto the ground truth (monocular poses have no scale), and the error
is ``sqrt(sum |scale·pred - gt|²) / frames``. Ground truth comes as KITTI odometry poses: a 3x4
camera-to-world matrix per frame, row-major, one line each (the synthetic sequences' ``poses.txt``).
"""

from __future__ import annotations

import os
from typing import Sequence

import numpy as np

from .errors import DataError

TRACK_LENGTH = 5  # Monodepth2's snippet length


def read_poses(path: str | os.PathLike) -> np.ndarray:
    """(N, 4, 4) camera-to-world poses of a KITTI odometry poses file; a DataError names a bad file."""
    try:
        rows = np.loadtxt(path, ndmin=2)
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: cannot read poses ({exc})") from None
    if rows.shape[1] != 12 or not len(rows) or not np.isfinite(rows).all():
        raise DataError(f"{path}: expected 12 finite numbers per line (a 3x4 pose), got shape {rows.shape}")
    bottom = np.tile([[[0.0, 0.0, 0.0, 1.0]]], (len(rows), 1, 1))
    return np.concatenate((rows.reshape(-1, 3, 4), bottom), axis=1)


def local_poses(global_poses: np.ndarray) -> np.ndarray:
    """(N - 1, 4, 4) poses from each frame's camera to the next one's, of (N, 4, 4) camera-to-world
    poses (Monodepth2's ``gt_local_poses``: ``inv(inv(G[i-1]) · G[i])``)."""
    return np.stack(
        [
            np.linalg.inv(np.linalg.inv(a) @ b)
            for a, b in zip(global_poses[:-1], global_poses[1:], strict=True)
        ]
    )


def dump_xyz(transformations: Sequence[np.ndarray]) -> np.ndarray:
    """(len + 1, 3) camera positions of a chain of relative poses, the first at the origin
    (Monodepth2's ``dump_xyz``)."""
    cam_to_world = np.eye(4)
    xyzs = [cam_to_world[:3, 3]]
    for transformation in transformations:
        cam_to_world = cam_to_world @ transformation
        xyzs.append(cam_to_world[:3, 3])
    return np.array(xyzs)


def compute_ate(gt_xyz: np.ndarray, pred_xyz: np.ndarray) -> float:
    """Monodepth2's ``compute_ate``: RMSE-like error of ``pred_xyz`` (F, 3) against ``gt_xyz`` after
    moving its first position onto the ground truth's and the least-squares scale. A prediction
    that stays at one point gets scale 0 (Monodepth2's division gives NaN there)."""
    aligned = pred_xyz + (gt_xyz[0] - pred_xyz[0])[None, :]
    norm = np.sum(aligned**2)
    scale = np.sum(gt_xyz * aligned) / norm if norm > 0 else 0.0
    return float(np.sqrt(np.sum((aligned * scale - gt_xyz) ** 2)) / gt_xyz.shape[0])


def snippet_ates(
    predicted: np.ndarray, ground_truth: np.ndarray, track_length: int = TRACK_LENGTH
) -> np.ndarray:
    """The ATE of every snippet of ``track_length`` frames: ``predicted`` (N - 1, 4, 4) relative
    poses of consecutive frames, ``ground_truth`` (N, 4, 4) camera-to-world poses of the same N
    frames. As Monodepth2, snippets start at every frame; those near the end are shorter."""
    if len(predicted) != len(ground_truth) - 1 or len(ground_truth) < 2:
        raise ValueError(
            f"snippet_ates: need N >= 2 ground-truth poses and N - 1 predicted, got "
            f"{len(ground_truth)} and {len(predicted)}"
        )
    gt_local = local_poses(ground_truth)
    ates = []
    for i in range(len(ground_truth) - 1):
        snippet = slice(i, i + track_length - 1)
        ates.append(compute_ate(dump_xyz(gt_local[snippet]), dump_xyz(predicted[snippet])))
    return np.array(ates)
