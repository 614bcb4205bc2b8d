"""Where each data source's files live under ``data.root``: paths only, no I/O.

Apart from the indexes (:mod:`msdepth.data.eval_index`, :mod:`msdepth.data.indexing`) so that a
stage needing only the paths (``prepare_data``) does not import, and so depend on, the indexing code.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from msdepth.config.params import Params

MONO_SPLIT = "train_mono_files.txt"  # below a synthetic root
KITTI2012 = "kitti2012"  # below data.root: data_stereo_flow.zip extracted (training/, testing/)
# eval.extra_sets' kitti2015 beside a synthetic training set: data_scene_flow.zip's training/ below
# data.root/kitti2015_stereo, as the renderer's own kitti2015/ holds the synthetic evaluation frames.
KITTI2015_SET = "kitti2015_stereo"


@dataclass(frozen=True)
class Layout:
    """Paths of one data source's KITTI-format tree.

    ``rois`` is the exact box file of the synthetic set; real KITTI has none (``None``): its
    boxes come from ``obj_map`` and the user's CSV (:mod:`msdepth.data.rois`).
    """

    raw_root: Path
    train_split: Path
    kitti2015_root: Path
    eval_split: Path
    rois: Path | None
    # The extra evaluation sets' lists (msdepth.data.eval_sets) and the KITTI depth benchmark's
    # annotated GT (data_depth_annotated.zip's train/ and val/).
    eigen_split: Path
    eigen_benchmark_split: Path
    depth_annotated: Path
    # Monodepth2's split of frames with both neighbours (msdepth.data.sequences), for train.mode
    # mono and mono_stereo: KITTI's eigen_zhou list, or the synthetic set's (sequence_length > 0).
    mono_split: Path | None = None
    # KITTI odometry (sequences/<NN>/image_2, poses/<NN>.txt) for the monocular runs' pose ATE.
    odometry: Path | None = None
    # eval.extra_sets' kitti2012: data_stereo_flow.zip's training/ (msdepth.data.kitti2012), extracted
    # into kitti2012/ below data.root as data_scene_flow.zip is into kitti2015/.
    kitti2012_root: Path | None = None
    # eval.extra_sets' kitti2015 (KITTI 2015's training/): data.source kitti's own kitti2015/
    # tree; beside the synthetic set, KITTI2015_SET.
    kitti2015_set_root: Path | None = None


@dataclass(frozen=True)
class FolderLayout:
    """Paths of a stereo folder (``data.source: folder``, :mod:`msdepth.data.folder`): every
    ``data.folder.*`` path below the folder (``data.root``). ``pairs``, ``rois_csv`` and
    ``class_maps``: None = not given."""

    root: Path
    left: Path
    right: Path
    pairs: Path | None
    camera: Path
    eval_list: Path
    rois_csv: Path | None
    class_maps: Path | None = None


def folder_layout(params: Params) -> FolderLayout:
    """The stereo folder's paths from ``data.folder`` (the folder is ``data.root``)."""
    f = params.data.folder
    root = Path(f.root or params.data.root)
    return FolderLayout(
        root,
        root / f.left,
        root / f.right,
        root / f.pairs if f.pairs else None,
        root / f.camera,
        root / f.eval_list,
        root / f.rois_csv if f.rois_csv else None,
        root / f.class_maps if f.class_maps else None,
    )


def layout(params: Params) -> Layout:
    """The paths for ``params.data.source``: both KITTI-format sources share one tree shape under
    ``data.root``. A stereo folder has its own (:func:`folder_layout`)."""
    if params.data.source == "folder":
        raise ValueError("data.source folder has no KITTI-format layout: use folder_layout()")
    root = Path(params.data.root)
    if params.data.source == "synthetic":
        return Layout(
            root / "raw",
            root / "train_files.txt",
            root / "kitti2015",
            root / "kitti2015" / "test_files.txt",
            root / "rois.csv",
            root / "eigen_test_files.txt",
            root / "eigen_benchmark_test_files.txt",
            root / "depth_annotated",
            root / MONO_SPLIT,
            kitti2012_root=root / KITTI2012 / "training",
            kitti2015_set_root=root / KITTI2015_SET / "training",
        )
    k = params.data.kitti
    return Layout(
        root / "raw",
        Path(k.train_split),
        root / "kitti2015",
        Path(k.eval_split),
        None,
        Path(k.eigen_split),
        Path(k.eigen_benchmark_split),
        root / k.depth_annotated,
        Path(k.mono_split),
        root / k.odometry,
        root / KITTI2012 / "training",
        root / "kitti2015" / "training",
    )
