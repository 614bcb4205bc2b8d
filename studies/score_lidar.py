"""Score depth maps (``*_depth.npy`` of ``msdepth predict`` or ``msdepth optimum``) against one
KITTI Velodyne scan projected into the left camera, the Eigen-style raw-LiDAR GT.

The projection is the evaluation's (:func:`msdepth.data.kitti.lidar_depth_map`); the metrics are
Monodepth's (:func:`msdepth.evaluation.metrics.compute_errors`) on GT in (1e-3, cap) m with predictions
clamped to that range, as the Eigen evaluation does. With an object-benchmark ``calib.txt``
(``P2``, ``R0_rect``, ``Tr_velo_to_cam``)::

    S=../shared/real-samples/kitti-object-pair
    msdepth optimum $S/left.png $S/right.png --variant ssim --out /tmp/opt/ssim \\
        --focal 721.5377 --baseline 0.5327
    python studies/score_lidar.py --scan $S/lidar.bin --calib $S/calib.txt /tmp/opt/*/left_*_depth.npy
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from msdepth.errors import run_main
from msdepth.evaluation.metrics import compute_errors
from msdepth.geometry.depth import clamp_depth
from msdepth.studies.real_samples import MIN_DEPTH, lidar_gt


def score(depth: np.ndarray, gt: np.ndarray, cap: float) -> dict[str, float]:
    """Monodepth's metrics over the GT pixels in (1e-3, cap) m. A depth of 0 is read as beyond
    the writer's ``max_depth`` (80 m; the optimum's disparities are never 0), so as the cap."""
    valid = (gt > MIN_DEPTH) & (gt < cap)
    pred = np.where(depth[valid] > 0, depth[valid], cap)
    return compute_errors(gt[valid], clamp_depth(pred, MIN_DEPTH, cap))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("depths", nargs="+", type=Path, help="*_depth.npy files (m) at the image's resolution")
    ap.add_argument("--scan", type=Path, required=True)
    ap.add_argument("--calib", type=Path, required=True)
    ap.add_argument("--cap", type=float, default=80.0)
    args = ap.parse_args(argv)
    print("| depth map | GT points | abs_rel | rmse | a1 |\n|---|---|---|---|---|")
    first = np.load(args.depths[0])
    gt = lidar_gt(args.scan, args.calib, first.shape)
    oracle = np.full(first.shape, np.median(gt[(gt > MIN_DEPTH) & (gt < args.cap)]), np.float32)
    m = score(oracle, gt, args.cap)
    print(f"| oracle constant (median GT depth) | | {m['abs_rel']:.3f} | {m['rmse']:.2f} | {m['a1']:.3f} |")
    for path in args.depths:
        depth = np.load(path)
        gt = lidar_gt(args.scan, args.calib, depth.shape)
        m = score(depth, gt, args.cap)
        points = int(((gt > MIN_DEPTH) & (gt < args.cap)).sum())
        print(f"| {path} | {points} | {m['abs_rel']:.3f} | {m['rmse']:.2f} | {m['a1']:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/score_lidar.py", main))
