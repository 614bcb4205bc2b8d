"""The evaluation index: one row per frame (:data:`EVAL_COLUMNS`), the same format for every set.

KITTI 2015's is built from its split (:func:`build_eval_index`); the extra sets' by
:mod:`msdepth.data.eval_sets`, a stereo folder's by :mod:`msdepth.data.folder`. The index stage
writes them all (:mod:`msdepth.data.indexing`); every later stage reads them back here
(:func:`read_eval_index`), never the source. Also the paths of a raw frame's ground truth
(:func:`training_gt_path`, :func:`velodyne_path`).

Both KITTI-format sources share one layout under ``data.root`` (:mod:`msdepth.data.layout`):
``raw/`` (KITTI raw: ``<date>/<drive>_sync/image_02|image_03/data``) and ``kitti2015/``
(``training/image_2``, ``image_3``, ``disp_noc_0``, ``disp_occ_0``, ``obj_map``), plus the
split lists.
"""

from __future__ import annotations

import os
from pathlib import Path

import pandas as pd

from msdepth.data import kitti
from msdepth.data.pairs import check_same_size
from msdepth.errors import DataError
from msdepth.io import atomic_path
from msdepth.pipeline.paths import SET_INDEXES, SET_ROIS
from msdepth.readers import read_table_file

# One evaluation index format for every set (msdepth.data.eval_sets): ``gt`` is a file of kind
# ``gt_kind`` (msdepth.data.ground_truth.GT_KINDS), ``calib`` the raw day folder of a Velodyne
# frame, ``crop`` the set's evaluation crop ("" = none), obj_map and class_map optional (""): a
# frame's exact classes (msdepth.data.ground_truth.read_frame_classes).
EVAL_COLUMNS = (
    "frame", "left", "right", "gt", "gt_kind", "calib", "crop", "obj_map", "class_map", "focal", "baseline"
)  # fmt: skip


def training_gt_path(left_image: Path) -> Path:
    """GT disparity of a synthetic training frame: ``image_02/data/X.png`` -> ``disp_02/data/X.png``.

    Real KITTI raw drives have no dense GT; only the synthetic set writes ``disp_02``. Theirs is
    the Velodyne scan (:func:`velodyne_path`).
    """
    return left_image.parent.parent.parent / "disp_02" / "data" / (left_image.stem + ".png")


def velodyne_path(left_image: Path) -> Path:
    """Velodyne scan of a KITTI raw frame: ``image_02/data/X.png`` -> ``velodyne_points/data/X.bin``.

    Its day's calibration (``calib_cam_to_cam.txt``, ``calib_velo_to_cam.txt``) is in the folder
    above the drive: ``velodyne_path(left).parents[3]``.
    """
    return left_image.parent.parent.parent / "velodyne_points" / "data" / (left_image.stem + ".bin")


def build_eval_index(kitti2015_root: Path, split_file: Path, gt: str) -> pd.DataFrame:
    """One row per KITTI 2015 evaluation frame: image/GT paths, focal and baseline."""
    rows, missing = [], []
    for left_rel, _ in kitti.read_split(split_file):
        frame = Path(left_rel).stem
        paths = kitti.kitti2015_paths(kitti2015_root, frame, gt)
        left = kitti.resolve_image(kitti2015_root, left_rel)
        right = kitti.resolve_image(
            kitti2015_root, str(Path(left_rel).parent.parent / "image_3" / Path(left_rel).name)
        )
        if left is None or right is None or not Path(paths["disp"]).exists():
            missing.append(frame)
            continue
        shape = kitti.read_image(left).shape[:2]
        check_same_size(left, shape, right, kitti.read_image(right).shape, "right image")
        check_same_size(
            left, shape, Path(paths["disp"]), kitti.read_disparity(paths["disp"]).shape, f"{gt} GT"
        )
        width = shape[1]
        focal, baseline = kitti.focal_and_baseline(width, paths["calib"])
        obj_map = paths["obj_map"] if Path(paths["obj_map"]).exists() else ""
        class_map = paths["class_map"] if Path(paths["class_map"]).exists() else ""  # synthetic only
        if class_map:
            check_same_size(left, shape, Path(class_map), kitti.read_class_map(class_map).shape, "class map")
        rows.append(
            (
                frame,
                str(left),
                str(right),
                str(paths["disp"]),
                "disparity",
                "",
                "",
                str(obj_map),
                str(class_map),
            )
            + (focal, baseline)
        )
    if not rows:
        raise DataError(f"{split_file}: no evaluation frame with images and {gt} GT under {kitti2015_root}")
    if missing:
        raise DataError(
            f"{split_file}: {len(missing)} evaluation frame(s) missing under {kitti2015_root}: {missing[:10]}"
        )
    return pd.DataFrame(rows, columns=list(EVAL_COLUMNS))


def set_index_path(index_dir: str | os.PathLike, name: str) -> Path:
    """The evaluation index of extra set ``name`` below the index folder."""
    return Path(index_dir) / SET_INDEXES.name / f"{name}.csv"


def set_rois_path(index_dir: str | os.PathLike, name: str) -> Path:
    """The ROI boxes of extra set ``name`` below the index folder (the ``rois`` stage's; its
    contact sheet beside it, ``.png``)."""
    return Path(index_dir) / SET_ROIS.name / f"{name}.csv"


def write_eval_index(path: Path, frames: pd.DataFrame) -> None:
    """Write the evaluation index CSV atomically."""
    with atomic_path(path) as tmp:
        frames.to_csv(tmp, index=False)


def read_eval_index(path: str | os.PathLike) -> pd.DataFrame:
    """Read the evaluation index written by :func:`msdepth.data.indexing.build_indexes`."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: no evaluation index (run the index stage)")
    text = {c: str for c in EVAL_COLUMNS if c not in ("focal", "baseline")}
    frames = read_table_file(path, "evaluation index", dtype=text, keep_default_na=False)
    missing = set(EVAL_COLUMNS) - set(frames.columns)
    if missing:
        raise DataError(
            f"{path}: missing columns {sorted(missing)} (an older index format: run the index stage)"
        )
    return frames
