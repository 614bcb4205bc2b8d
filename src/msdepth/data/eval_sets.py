"""The evaluation sets beside KITTI 2015: one index builder per set, one index format for all.

- ``eigen``: the Eigen split (697 frames of 28 raw drives), GT = the frame's Velodyne scan
  projected with the day's calibration, as Monodepth and Monodepth2 evaluate it;
- ``eigen_benchmark``: its 652 frames with KITTI's improved, accumulated GT (Uhrig et al. 2017,
  ``data_depth_annotated.zip``);
- ``kitti2012``: KITTI 2012's stereo training frames (``data_stereo_flow.zip``'s ``training/``,
  :mod:`msdepth.data.kitti2012`), GT ``disp_occ`` with ``disp_refl_occ``'s reflective surfaces, and
  those pixels as the exact-mask class ``reflective`` (the index's ``class_map`` column);
- ``kitti2015``: KITTI 2015's stereo training frames (``data_scene_flow.zip``'s ``training/``) beside
  a training set of another source, GT ``disp_occ_0`` (every pixel with GT, KITTI's D1-all, as
  ``kitti2012`` takes ``disp_occ``) and, where ``obj_map/`` has the frame, its cars (fitted CAD
  models) as the exact-mask class ``car`` (:func:`_build_kitti2015_index`);
- ``folder``: a stereo folder's evaluation list (``data.folder.*`` with ``data.folder.root`` naming
  it, :mod:`msdepth.data.folder`) beside a training set of another source: its GT, camera and
  class maps (``data.folder.class_maps``: e.g. a Middlebury- or Booster-style set's transparent and
  specular masks) as exact classes, as ``data.source: folder`` evaluates it.

The Eigen sets are evaluated inside Garg's crop with GT in (min_depth, cap), KITTI 2012 and 2015 on
the whole frame as ``data.source: kitti``'s KITTI 2015 frames (:mod:`msdepth.evaluation.suites`). Each
builder returns rows of :data:`msdepth.data.eval_index.EVAL_COLUMNS`, so the suites read every set the
same way (:func:`msdepth.evaluation.suites.load_frames`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import pandas as pd

from msdepth.config.params import Params
from msdepth.data import folder, kitti, kitti2012
from msdepth.data.eval_index import EVAL_COLUMNS, velodyne_path
from msdepth.data.layout import folder_layout, layout
from msdepth.data.pairs import check_same_size
from msdepth.errors import DataError

CROP = "garg"


def _frame_name(left: Path) -> str:
    """``<drive>_sync_<frame>``: unique over the raw tree (dates are part of the drive name)."""
    return f"{left.parents[2].name}_{left.stem}"


def _camera(left: Path, day: Path) -> tuple[float, float]:
    """Focal (px) and baseline (m) of a raw frame from its day's ``calib_cam_to_cam.txt``, as
    Monodepth's Eigen evaluation takes them."""
    path = day / "calib_cam_to_cam.txt"
    try:
        return kitti.stereo_from_calib(kitti.read_calib(path))
    except DataError as exc:
        raise DataError(f"{path} (for {left}): {exc}") from None


def _raw_row(raw_root: Path, left_rel: str, right_rel: str) -> tuple[Path, Path, Path] | None:
    """(left, right, day folder) of a listed raw frame, None if either image is missing."""
    left, right = kitti.resolve_image(raw_root, left_rel), kitti.resolve_image(raw_root, right_rel)
    if left is None or right is None:
        return None
    check_same_size(left, kitti.read_image(left).shape, right, kitti.read_image(right).shape, "right image")
    return left, right, left.parents[3]


def _finish(rows: list[tuple], missing: list[str], split: Path, what: str) -> pd.DataFrame:
    if missing:
        raise DataError(
            f"{split}: {len(missing)} of {len(rows) + len(missing)} frame(s) lack {what}, e.g. {missing[:5]} "
            "(download those drives, or leave the set out of eval.extra_sets)"
        )
    if not rows:
        raise DataError(f"{split}: lists no frame")
    return pd.DataFrame(rows, columns=list(EVAL_COLUMNS))


def _build_eigen_index(raw_root: Path, split: Path) -> pd.DataFrame:
    """The Eigen split's frames: left/right images, Velodyne scan, day folder, camera."""
    rows, missing = [], []
    for left_rel, right_rel in kitti.read_split(split):
        found = _raw_row(raw_root, left_rel, right_rel)
        scan = velodyne_path(found[0]) if found else None
        if found is None or not scan.is_file():
            missing.append(left_rel)
            continue
        left, right, day = found
        shape = kitti.read_raw_calib(day).shape
        image_shape = kitti.read_image(left).shape
        if tuple(image_shape[:2]) != shape:
            raise DataError(f"{left} is {tuple(image_shape[:2])} but S_rect_02 of {day} says {shape}")
        focal, baseline = _camera(left, day)
        row = (_frame_name(left), str(left), str(right), str(scan), "velodyne", str(day), CROP, "", "")
        rows.append((*row, focal, baseline))
    return _finish(rows, missing, split, "images or a velodyne_points scan under " + str(raw_root))


def _read_benchmark_split(path: Path) -> list[tuple[str, int]]:
    """Monodepth2's ``<date>/<drive>_sync <frame number> l`` lines as (drive folder, frame number).

    Read as every list file is (:func:`msdepth.data.kitti.list_lines`: a regular UTF-8 file of at
    most :data:`msdepth.data.kitti.MAX_LIST_BYTES`); a file listing no frame is a DataError.
    """
    out = []
    for i, line, parts in kitti.list_lines(path, "no such split file"):
        if len(parts) != 3 or parts[2] != "l" or not parts[1].isdigit():
            # cut: one line of a hostile file can be the whole list bound long
            raise DataError(f"{path}:{i}: expected '<date>/<drive>_sync <frame> l', got {line[:200]!r}")
        out.append((parts[0], int(parts[1])))
    if not out:
        raise DataError(f"{path}: split file lists no frame")
    return out


def _annotated_gt_path(annotated_root: Path, drive: str, number: int) -> Path | None:
    """The depth benchmark's GT of a frame, None if absent:
    ``{train,val}/<drive>_sync/proj_depth/groundtruth/image_02/<n:010d>.png``."""
    for part in ("train", "val"):
        path = annotated_root / part / Path(drive).name / "proj_depth" / "groundtruth" / "image_02"
        path = path / f"{number:010d}.png"
        if path.is_file():
            return path
    return None


def _build_eigen_benchmark_index(raw_root: Path, split: Path, annotated_root: Path) -> pd.DataFrame:
    """The Eigen benchmark frames: raw images, annotated depth GT, day folder, camera."""
    rows, missing = [], []
    for drive, number in _read_benchmark_split(split):
        name = f"{number:010d}.png"
        found = _raw_row(raw_root, f"{drive}/image_02/data/{name}", f"{drive}/image_03/data/{name}")
        gt = _annotated_gt_path(annotated_root, drive, number)
        if found is None or gt is None:
            missing.append(f"{drive} {number}")
            continue
        left, right, day = found
        check_same_size(left, kitti.read_image(left).shape, gt, kitti.read_depth(gt).shape, "annotated GT")
        focal, baseline = _camera(left, day)
        row = (_frame_name(left), str(left), str(right), str(gt), "depth", str(day), CROP, "", "")
        rows.append((*row, focal, baseline))
    return _finish(
        rows, missing, split, f"raw images under {raw_root} or annotated GT under {annotated_root}"
    )


def _build_kitti2012_index(root: Path) -> pd.DataFrame:
    """KITTI 2012's frames under its ``training/`` folder ``root``: images, GT (kind ``kitti2012``),
    the ``disp_refl_occ`` PNG as the class map (class ``reflective``), camera
    (:func:`msdepth.data.kitti2012.camera`: ``calib/`` or the default by width)."""
    rows = []
    for frame in kitti2012.frames(root):
        paths = kitti2012.frame_paths(root, frame)
        shape = kitti.read_image(paths["left"]).shape
        check_same_size(
            paths["left"], shape, paths["right"], kitti.read_image(paths["right"]).shape, "right image"
        )
        for what in ("gt", kitti2012.REFLECTIVE):
            check_same_size(
                paths["left"], shape, paths[what], kitti.read_disparity(paths[what]).shape, what + " GT"
            )
        focal, baseline = kitti2012.camera(root, frame, shape[1])
        row = (frame, str(paths["left"]), str(paths["right"]), str(paths["gt"]), "kitti2012", "", "", "")
        rows.append((*row, str(paths[kitti2012.REFLECTIVE]), focal, baseline))
    return pd.DataFrame(rows, columns=list(EVAL_COLUMNS))


KITTI2015_GT = "disp_occ_0"  # the kitti2015 set's GT folder: every pixel with GT


def _build_kitti2015_index(root: Path) -> pd.DataFrame:
    """KITTI 2015's frames under its ``training/`` folder ``root``: the ``*_10.png`` of ``image_2/``
    with ``image_3/`` and ``disp_occ_0/`` (GT kind ``disparity``), ``obj_map/`` where present (class
    ``car``, :func:`msdepth.data.ground_truth.read_frame_classes`), camera by width or
    ``calib_cam_to_cam/`` (:func:`msdepth.data.kitti.focal_and_baseline`)."""
    left_dir = Path(root) / "image_2"
    if not left_dir.is_dir():
        raise DataError(f"{root}: no image_2/ folder (expected KITTI 2015's training/ layout)")
    names = sorted(p.stem for p in left_dir.glob("*_10.png"))
    if not names:
        raise DataError(f"{left_dir}: no *_10.png frame")
    rows = []
    for frame in names:
        paths = {
            key: Path(root) / path.relative_to(path.parents[1])  # below training/, whatever root's name
            for key, path in kitti.kitti2015_paths(Path(root), frame, KITTI2015_GT).items()
        }
        for what in ("right", "disp"):
            if not paths[what].is_file():
                raise DataError(f"{paths[what]}: missing (KITTI 2015 frame {frame})")
        shape = kitti.read_image(paths["left"]).shape
        check_same_size(
            paths["left"], shape, paths["right"], kitti.read_image(paths["right"]).shape, "right image"
        )
        check_same_size(paths["left"], shape, paths["disp"], kitti.read_disparity(paths["disp"]).shape, "GT")
        obj_map = paths["obj_map"] if paths["obj_map"].is_file() else ""
        if obj_map:
            check_same_size(paths["left"], shape, obj_map, kitti.read_obj_map(obj_map).shape, "obj_map")
        focal, baseline = kitti.focal_and_baseline(shape[1], paths["calib"])
        row = (frame, str(paths["left"]), str(paths["right"]), str(paths["disp"]), "disparity", "", "")
        rows.append((*row, str(obj_map), "", focal, baseline))
    return pd.DataFrame(rows, columns=list(EVAL_COLUMNS))


def folder_eval_index(params: Params) -> pd.DataFrame:
    """A stereo folder's evaluation index (:func:`msdepth.data.folder.eval_rows`: every listed frame's
    images, GT, camera and class map checked once here): ``data.source: folder``'s main set, or the
    extra set ``folder`` (the folder ``data.folder.root``)."""
    rows = folder.eval_rows(folder_layout(params), npy_is_disparity=params.data.folder.npy_is_disparity)
    return pd.DataFrame(rows, columns=list(EVAL_COLUMNS))


SETS: dict[str, Callable[[Params], pd.DataFrame]] = {
    "eigen": lambda p: _build_eigen_index(layout(p).raw_root, layout(p).eigen_split),
    "eigen_benchmark": lambda p: _build_eigen_benchmark_index(
        layout(p).raw_root, layout(p).eigen_benchmark_split, layout(p).depth_annotated
    ),
    "kitti2012": lambda p: _build_kitti2012_index(layout(p).kitti2012_root),
    "kitti2015": lambda p: _build_kitti2015_index(layout(p).kitti2015_set_root),
    "folder": folder_eval_index,
}


def build_set_index(params: Params, name: str) -> pd.DataFrame:
    """The evaluation index of extra set ``name`` (a key of :data:`SETS`)."""
    if name not in SETS:
        raise DataError(f"unknown evaluation set {name!r}; known: {sorted(SETS)}")
    return SETS[name](params)
