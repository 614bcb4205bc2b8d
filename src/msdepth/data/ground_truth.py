"""Evaluation ground truth as depth in metres, whatever form a set stores it in.

One reader for every evaluation set (:func:`read_gt_depth`), so the suites see the same data
model for KITTI 2015 (disparity PNGs), the Eigen split (Velodyne scans projected with the day's
calibration), the KITTI depth benchmark (depth PNGs) and a stereo folder (msdepth.data.folder:
PFM or .npy disparity, .npy depth, or no GT at all). The index says which form a frame has.

Also each frame's exact classes (:func:`read_frame_classes`), the bits of
:data:`msdepth.data.kitti.CLASS_BITS` whatever a set stores: the synthetic set's class map, KITTI
2012's reflective GT, KITTI 2015's ``obj_map`` cars, a stereo folder's labelled class maps
(:func:`read_label_class_map`, named by its classes file :func:`read_classes`).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from msdepth.config.checks import shown
from msdepth.config.params_yaml import read_data_file
from msdepth.data import kitti, kitti2012
from msdepth.data.imagefile import MAX_IMAGE_PIXELS, check_pixel_limit
from msdepth.data.pfm import read_pfm
from msdepth.errors import DataError
from msdepth.geometry.depth import disparity_to_depth
from msdepth.readers import read_npy_file

# The index's ``gt_kind`` column: what its ``gt`` file holds.
GT_KINDS = {
    "disparity": "KITTI disparity PNG (uint16, pixels x 256); depth = focal * baseline / disparity",
    "kitti2012": "KITTI 2012 disp_occ PNG, the sibling disp_refl_occ's reflective surfaces in its place",
    "depth": "KITTI depth-benchmark PNG (uint16, metres x 256)",
    "velodyne": "KITTI Velodyne scan (.bin), projected into camera 2 with the raw day's calibration",
    "pfm": "PFM disparity in px (Scene Flow, Middlebury); inf, NaN and <= 0 are invalid",
    "npy_depth": "NumPy .npy depth in metres (H, W); non-finite and <= 0 are invalid",
    "npy_disparity": "NumPy .npy disparity in px (H, W); non-finite and <= 0 are invalid",
    "none": "no GT: every pixel invalid; the gt column names the frame's left image, for its size",
}

# The largest .npy GT read: float64 samples at the image pixel limit, with a header of up to 64 KiB.
MAX_NPY_BYTES = 8 * MAX_IMAGE_PIXELS + (64 << 10)


def _valid_or_zero(values: np.ndarray) -> np.ndarray:
    """float32 with every non-finite or non-positive value set to 0 (= invalid)."""
    values = np.asarray(values, dtype=np.float32)
    return np.where(np.isfinite(values) & (values > 0), values, np.float32(0)).astype(np.float32)


def _disparity_depth(disp: np.ndarray, path: str | os.PathLike, focal: float, baseline: float) -> np.ndarray:
    if disp.ndim != 2:
        raise DataError(f"{path}: a disparity map must have one channel, got shape {disp.shape}")
    return disparity_to_depth(_valid_or_zero(disp), focal, baseline)


def _read_npy(path: str | os.PathLike) -> np.ndarray:
    """A 2-D numeric GT array from a ``.npy`` file: read by :func:`msdepth.readers.read_npy_file` (a
    regular file of at most :data:`MAX_NPY_BYTES`, its header checked against its size before the
    data is read), then held to the image pixel limit, as each value becomes a float32 depth."""
    values = read_npy_file(path, ".npy", MAX_NPY_BYTES)
    dtype = values.dtype
    if values.ndim != 2 or not (np.issubdtype(dtype, np.floating) or np.issubdtype(dtype, np.integer)):
        raise DataError(f"{path}: GT must be a 2-D numeric array, got {dtype} of shape {values.shape}")
    try:
        check_pixel_limit(values.shape[1], values.shape[0], MAX_IMAGE_PIXELS, "its .npy header")
    except DataError as exc:
        raise DataError(f"{path}: {exc}") from None
    return values


def read_gt_depth(
    kind: str, path: str | os.PathLike, *, calib: str | os.PathLike = "", focal: float, baseline: float
) -> np.ndarray:
    """GT depth (m, float32, 0 = none) of one evaluation frame from its ``kind`` of file.

    ``calib``: the raw day folder (``raw/<date>/``) of a ``velodyne`` frame, whose
    ``calib_cam_to_cam.txt`` and ``calib_velo_to_cam.txt`` project the scan (:func:`kitti.velodyne_depth`).
    """
    if kind == "disparity":
        return disparity_to_depth(kitti.read_disparity(path), focal, baseline)
    if kind == "kitti2012":
        return disparity_to_depth(kitti2012.read_gt_disparity(path)[0], focal, baseline)
    if kind == "depth":
        return kitti.read_depth(path)
    if kind == "velodyne":
        if not calib:
            raise DataError(
                f"{path}: a Velodyne GT frame needs its raw day folder (the index's calib column)"
            )
        return kitti.velodyne_depth(path, kitti.read_raw_calib(Path(calib)))
    if kind == "pfm":
        return _disparity_depth(read_pfm(path), path, focal, baseline)
    if kind == "npy_disparity":
        return _disparity_depth(_read_npy(path), path, focal, baseline)
    if kind == "npy_depth":
        return _valid_or_zero(_read_npy(path))
    if kind == "none":
        return np.zeros(kitti.read_image(path).shape[:2], np.float32)
    raise DataError(f"{path}: unknown GT kind {kind!r}; known: {sorted(GT_KINDS)}")


# A stereo folder's class maps (data.folder.class_maps) are <frame>.png beside this file, which
# names their labels: {label: class name}, e.g. {1: transparent, 2: specular}; 0 = no class.
CLASSES_FILE = "classes.yaml"
MAX_LABEL = 65535  # a 16-bit PNG's largest value


def read_classes(path: str | os.PathLike) -> dict[int, str]:
    """A classes file: ``{label: class name}``, labels 1..:data:`MAX_LABEL` (0 = no class, never listed),
    names of :data:`msdepth.data.kitti.CLASS_BITS`; one DataError naming the file otherwise."""
    raw = read_data_file(path, "classes file", "no classes file (label: class name, beside the class maps)")
    if not isinstance(raw, dict) or not raw:
        raise DataError(f"{path}: expected a mapping of labels to class names, e.g. {{1: transparent}}")
    for label, name in raw.items():
        if isinstance(label, bool) or not isinstance(label, int) or not 1 <= label <= MAX_LABEL:
            raise DataError(f"{path}: label {shown(label)} must be an integer 1..{MAX_LABEL} (0 = no class)")
        if not isinstance(name, str):  # a list or mapping is no name (and cannot be looked up)
            known = list(kitti.CLASS_BITS)
            raise DataError(
                f"{path}: label {label}: expected one class name, got {shown(name)}; known: {known}"
            )
        if name not in kitti.CLASS_BITS:
            raise DataError(
                f"{path}: label {label}: unknown class {shown(name)}; known: {list(kitti.CLASS_BITS)}"
            )
    return raw


def read_label_class_map(path: str | os.PathLike, classes: dict[int, str] | None = None) -> np.ndarray:
    """A stereo folder's class map as bits of :data:`msdepth.data.kitti.CLASS_BITS`: its PNG of labels
    (:func:`msdepth.data.kitti.read_label_map`) through ``classes`` (default: the :data:`CLASSES_FILE`
    beside it). A label the classes do not name is a DataError naming the file and the labels."""
    classes = read_classes(Path(path).parent / CLASSES_FILE) if classes is None else classes
    labels = kitti.read_label_map(path)
    found = np.unique(labels)
    unknown = [int(v) for v in found if v and int(v) not in classes]
    if unknown:
        raise DataError(
            f"{path}: label(s) {unknown[:10]} not in its classes file (which names {sorted(classes)}; "
            "0 = no class)"
        )
    table = np.zeros(int(found.max()) + 1, np.uint8)
    for label, name in classes.items():
        if label < len(table):
            table[label] = kitti.CLASS_BITS[name]
    return table[labels]


def read_frame_classes(kind: str, class_map: str, obj_map: str) -> tuple[np.ndarray | None, bool]:
    """A frame's class map (bits of :data:`msdepth.data.kitti.CLASS_BITS`) from its index row (GT
    ``kind``; ``class_map`` and ``obj_map`` paths, "" = none), and whether its classes are scored
    over the whole frame (:func:`msdepth.evaluation.classes.exact_class_scores`, in the full-image
    suite): every set's but the synthetic set's, whose ROI classes have exact boxes (the ROI suite).

    - ``class_map`` of a KITTI 2012 frame: its ``disp_refl_occ`` PNG, the ``reflective`` class
      (:func:`msdepth.data.kitti2012.reflective_class_map`);
    - with a :data:`CLASSES_FILE` beside it: a stereo folder's labels (:func:`read_label_class_map`);
    - any other: a class map PNG of bits, the synthetic set's (:func:`msdepth.data.kitti.read_class_map`);
    - no class map but an ``obj_map`` (KITTI 2015): class ``car`` on its pixels > 0, the cars'
      fitted CAD models. Only there: the synthetic set's class map already holds its cars.
    """
    if kind == "kitti2012" and class_map:
        return kitti2012.reflective_class_map(class_map), True
    if class_map and (Path(class_map).parent / CLASSES_FILE).is_file():
        return read_label_class_map(class_map), True
    if class_map:
        return kitti.read_class_map(class_map), False
    if obj_map:
        car = np.uint8(kitti.CLASS_BITS["car"])
        return np.where(kitti.read_obj_map(obj_map) > 0, car, np.uint8(0)), True
    return None, False
