"""KITTI 2012's stereo training set (``data_stereo_flow.zip``'s ``training/``) as evaluation frames.

Layout: ``colored_0/<frame>.png`` (left, camera 2), ``colored_1/`` (right, camera 3), ``disp_occ/``
(GT disparity of every pixel KITTI has a LiDAR point for), ``disp_refl_occ/`` (GT disparity of the
**reflective surfaces only**: cars' paint and glass, from fitted CAD models) and, in the full
download, ``calib/<frame without _10>.txt`` (``P0`` .. ``P3``). Disparity PNGs: uint16, value / 256,
0 = no GT (the KITTI devkit's encoding, :func:`msdepth.data.kitti.read_disparity`).

``disp_refl_occ`` is not a superset of ``disp_occ``: checked on the shared frames, ``000001_10``
has 109,555 ``disp_occ`` pixels and 28,568 ``disp_refl_occ`` ones, of which 25,013 have no
``disp_occ`` value and 3,555 have both, disagreeing by up to 58 px there (``disp_occ``'s LiDAR
points seen through the glass, behind the surface the CAD model puts there); ``000000_10``: 162,583
and 58 (25 shared). So the GT of a frame here is ``disp_occ`` with ``disp_refl_occ`` taking its
place where it has a value (:func:`read_gt_disparity`: the surface the camera sees, as
PracticalDeepStereo combines them), and the exact-mask class ``reflective`` is every pixel with a
``disp_refl_occ`` value (:data:`REFLECTIVE`).

Camera: ``calib/<n>.txt``'s ``P2``/``P3`` when present; else a default by image width
(:data:`DEFAULT_FOCAL`, baseline 0.54 m as Monodepth takes KITTI's). KITTI 2012's frames come from
the odometry drives' rectification: 1226 px wide = focal 707.0912 px (sequences 04–12), 1241 =
718.856, 1242 = 721.5377 (sequence 03), 1224 = 707.0493. abs_rel depends on focal·baseline only
through the depth cap, and D1/EPE not at all.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from msdepth.data import kitti
from msdepth.errors import DataError

LEFT, RIGHT, GT, REFLECTIVE_GT, CALIB = "colored_0", "colored_1", "disp_occ", "disp_refl_occ", "calib"
REFLECTIVE = "reflective"  # the exact-mask class of disp_refl_occ's pixels (kitti.CLASS_BITS)
# px by image width, for frames without calib/ (the shared sample): the KITTI odometry calibrations.
DEFAULT_FOCAL = {1226: 707.0912, 1224: 707.0493, 1241: 718.856, 1242: 721.5377, 1238: 718.3351}
ARCHIVE = "data_stereo_flow.zip"  # KITTI's download (about 2 GB); its training/ is the set's root


def _reflective_path(gt_path: str | os.PathLike) -> Path:
    """The ``disp_refl_occ`` PNG beside a frame's ``disp_occ`` PNG (same name, sibling folder)."""
    gt_path = Path(gt_path)
    return gt_path.parent.parent / REFLECTIVE_GT / gt_path.name


def read_gt_disparity(gt_path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """A frame's GT disparity (px, float32, 0 = none) and its reflective pixels (bool), from its
    ``disp_occ`` PNG and the sibling ``disp_refl_occ`` one, which replaces it where it has a value
    (module docstring: the reflective surface, not the LiDAR point behind the glass)."""
    occ = kitti.read_disparity(gt_path)
    refl_path = _reflective_path(gt_path)
    refl = kitti.read_disparity(refl_path)
    if refl.shape != occ.shape:
        raise DataError(f"{refl_path}: {refl.shape} but {gt_path} is {occ.shape}")
    reflective = refl > 0
    return np.where(reflective, refl, occ).astype(np.float32), reflective


def reflective_class_map(reflective_gt: str | os.PathLike) -> np.ndarray:
    """A frame's class map (uint8, :data:`msdepth.data.kitti.CLASS_BITS`) from its ``disp_refl_occ``
    PNG: the ``reflective`` bit on every pixel with a value there."""
    bit = np.uint8(kitti.CLASS_BITS[REFLECTIVE])
    return np.where(kitti.read_disparity(reflective_gt) > 0, bit, np.uint8(0))


def camera(root: Path, frame: str, width: int) -> tuple[float, float]:
    """Focal (px) and baseline (m) of ``frame`` (``000000_10``): ``calib/000000.txt``'s ``P2``/``P3``
    when the file exists, else :data:`DEFAULT_FOCAL` [width] and 0.54 m."""
    path = Path(root) / CALIB / f"{frame.split('_')[0]}.txt"
    if path.is_file():
        try:
            return kitti.stereo_from_calib(kitti.read_calib(path))
        except DataError as exc:
            raise DataError(f"{path}: {exc}") from None
    if width not in DEFAULT_FOCAL:
        raise DataError(
            f"{root}: frame {frame} is {width} px wide, not a KITTI 2012 width ({sorted(DEFAULT_FOCAL)}), "
            f"and has no {path}"
        )
    return DEFAULT_FOCAL[width], kitti.KITTI_BASELINE


def frames(root: Path) -> list[str]:
    """The frames of a KITTI 2012 training folder: the ``*_10.png`` of ``colored_0/`` (the
    reference frames; ``_11`` is the flow benchmark's second frame), sorted; DataError if none."""
    left = Path(root) / LEFT
    if not left.is_dir():
        raise DataError(f"{root}: no {LEFT}/ folder (expected KITTI 2012's training/ layout)")
    names = sorted(p.stem for p in left.glob("*_10.png"))
    if not names:
        raise DataError(f"{left}: no *_10.png frame")
    return names


def frame_paths(root: Path, frame: str) -> dict[str, Path]:
    """The files of one frame: ``left``, ``right``, ``gt`` (disp_occ), ``reflective`` (disp_refl_occ);
    DataError naming the first that is missing."""
    root = Path(root)
    paths = {
        "left": root / LEFT / f"{frame}.png",
        "right": root / RIGHT / f"{frame}.png",
        "gt": root / GT / f"{frame}.png",
        REFLECTIVE: root / REFLECTIVE_GT / f"{frame}.png",
    }
    for path in paths.values():
        if not path.is_file():
            raise DataError(f"{path}: missing (KITTI 2012 frame {frame})")
    return paths
