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

from msdepth.data.kitti import MAX_CALIB_SIDE, read_calib
from msdepth.errors import ConfigError, DataError, run_main
from msdepth.evaluation.metrics import compute_errors
from msdepth.geometry.depth import clamp_depth
from msdepth.studies.real_samples import MIN_DEPTH, lidar_gt

# The object benchmark's calib.txt entries the projection reads, and their sizes (3x4, 3x3, 3x4).
CALIB_KEYS = {"P2": 12, "R0_rect": 9, "Tr_velo_to_cam": 12}


def score(depth: np.ndarray, gt: np.ndarray, cap: float) -> dict[str, float]:
    """Monodepth's metrics over the GT pixels in (1e-3, cap) m. A depth of 0 is read as beyond
    the writer's ``max_depth`` (80 m; the optimum's disparities are never 0), so as the cap."""
    valid = (gt > MIN_DEPTH) & (gt < cap)
    pred = np.where(depth[valid] > 0, depth[valid], cap)
    return compute_errors(gt[valid], clamp_depth(pred, MIN_DEPTH, cap))


def check_calib(path: Path) -> None:
    """``path`` holds the object benchmark's ``P2``, ``R0_rect`` and ``Tr_velo_to_cam``, or a
    DataError names what it lacks (a raw day's ``calib_cam_to_cam.txt`` has none of them)."""
    calib = read_calib(path)
    wrong = [f"{k} ({n} values)" for k, n in CALIB_KEYS.items() if k not in calib or calib[k].size != n]
    if wrong:
        raise DataError(f"{path}: not an object-benchmark calib.txt: needs {', '.join(wrong)}")


def load_depth(path: Path) -> np.ndarray:
    """A depth map (m) as ``msdepth predict``/``optimum`` write it, a 2-D ``.npy`` of numbers, or a
    DataError naming the file."""
    try:
        depth = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: not a readable .npy depth map ({exc})") from None
    if not isinstance(depth, np.ndarray) or depth.ndim != 2 or depth.dtype.kind not in "fiu":
        what = f"{depth.dtype} {depth.shape}" if isinstance(depth, np.ndarray) else "an .npz archive"
        raise DataError(f"{path}: a depth map must be a 2-D array of depths (m), got {what}")
    if not (0 < min(depth.shape) and max(depth.shape) <= MAX_CALIB_SIDE):
        raise DataError(f"{path}: a depth map must be 1..{MAX_CALIB_SIDE} px a side, got {depth.shape}")
    return depth


def in_range_gt(scan: Path, calib: Path, path: Path, shape: tuple[int, int], cap: float) -> np.ndarray:
    """The scan's depth in the image of the depth map ``path`` (``lidar_gt``), or a DataError where
    no point lands in it within (1e-3, cap) m (nothing to score)."""
    gt = lidar_gt(scan, calib, shape)
    if not ((gt > MIN_DEPTH) & (gt < cap)).any():
        raise DataError(
            f"{scan}: no LiDAR point lands in the {shape[0]}x{shape[1]} image of {path} "
            f"within ({MIN_DEPTH:g}, {cap:g}) m"
        )
    return gt


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("depths", nargs="+", type=Path, help="*_depth.npy files (m) at the image's resolution")
    ap.add_argument("--scan", type=Path, required=True)
    ap.add_argument("--calib", type=Path, required=True)
    ap.add_argument("--cap", type=float, default=80.0)
    args = ap.parse_args(argv)
    if not MIN_DEPTH < args.cap < np.inf:
        raise ConfigError(f"--cap: must be a depth (m) above {MIN_DEPTH:g}, got {args.cap}")
    check_calib(args.calib)
    depths = [(path, load_depth(path)) for path in args.depths]  # every map checked before any row
    first = depths[0][1]
    gt = in_range_gt(args.scan, args.calib, args.depths[0], first.shape, args.cap)
    print("| depth map | GT points | abs_rel | rmse | a1 |\n|---|---|---|---|---|")
    oracle = np.full(first.shape, np.median(gt[(gt > MIN_DEPTH) & (gt < args.cap)]), np.float32)
    m = score(oracle, gt, args.cap)
    print(f"| oracle constant (median GT depth) | | {m['abs_rel']:.3f} | {m['rmse']:.2f} | {m['a1']:.3f} |")
    for path, depth in depths:
        gt = in_range_gt(args.scan, args.calib, path, depth.shape, args.cap)
        m = score(depth, gt, args.cap)
        points = int(((gt > MIN_DEPTH) & (gt < args.cap)).sum())
        print(f"| {path} | {points} | {m['abs_rel']:.3f} | {m['rmse']:.2f} | {m['a1']:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/score_lidar.py", main))
