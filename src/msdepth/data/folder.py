"""Any rectified stereo set in one folder: ``data.source: folder``.

The folder is ``data.root`` (DVC tracks the data under that name); every other name below is a
``data.folder.*`` key, relative to it::

    <data.root>/
      left/000123.png ...     data.folder.left: the left images (.png, .jpg or .jpeg, any depth
      right/000123.png ...    data.folder.right: the right images, with the same relative names
      camera.yaml             data.folder.camera: focal_px, width_px, baseline_m
      eval.txt                data.folder.eval_list: "left right [gt]" per line
      gt/000123.pfm ...       the evaluation GT the list names (any place below the folder)
      rois.csv                data.folder.rois_csv (optional): boxes on the evaluation frames
      classes/                data.folder.class_maps (optional): the evaluation frames' classes
        classes.yaml          label: class name, e.g. "1: transparent" and "2: specular"
        000123.png ...        one PNG of integer labels per evaluation frame, named <frame>.png

- Training pairs: every left image with its right namesake, minus the evaluation list's left
  images (evaluation frames are never trained on). With ``data.folder.pairs`` (a file of
  ``left right`` relative paths, the format of :func:`msdepth.data.kitti.read_split`) the listed
  pairs instead, minus the evaluation frames too. A missing right image is an error naming it.
- Camera: ``focal_px`` is the focal length in pixels for images ``width_px`` wide; an image of
  another width (the same camera, resized) gets ``focal_px * width / width_px``. ``baseline_m``
  is the distance between the two cameras in metres.
- Evaluation list: ``left right [gt]``; the GT is optional per frame. A frame without GT is
  listed (it is predicted like every other) and the suites exclude it and count it. The GT's
  suffix says what it holds (:func:`gt_kind`): ``.png`` a KITTI disparity PNG (uint16, px x 256,
  0 = none), ``.pfm`` disparity in px as Scene Flow and Middlebury ship it (inf, NaN and <= 0 =
  none), ``.npy`` depth in metres, or disparity in px with ``data.folder.npy_is_disparity``.
  The frame's name (ROI CSV ``image`` column, metrics tables) is its left image's file stem.
- ROIs: only those of ``data.folder.rois_csv`` (there is no ``obj_map``); none is fine: the ROI
  suites then say they were skipped.
- Class maps (optional): with ``data.folder.class_maps``, every evaluation frame has one, the left
  image's size, 8- or 16-bit, 0 = no class; ``classes.yaml`` names each other label's class, one of
  :data:`msdepth.data.kitti.CLASS_BITS` (several labels may share one). The full-image suite then
  scores each class on its exact pixels, with D1 and EPE (:mod:`msdepth.evaluation.classes`).

``python -m msdepth export-folder`` writes such a folder from the synthetic set
(:mod:`msdepth.cli.folder_export`). This module imports neither torch nor the index code: the
``prepare_data`` stage checks a folder with it (:func:`check_folder`).
"""

from __future__ import annotations

import os
import stat
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from msdepth.config.params_yaml import read_data_file
from msdepth.data import kitti
from msdepth.data.ground_truth import CLASSES_FILE, read_classes, read_gt_depth, read_label_class_map
from msdepth.data.layout import FolderLayout
from msdepth.errors import DataError
from msdepth.io import write_text

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
CAMERA_KEYS = ("focal_px", "width_px", "baseline_m")
CAMERA_RANGES = kitti.CAMERA_RANGES


@dataclass(frozen=True)
class Camera:
    """A rectified stereo rig: focal length ``focal_px`` at image width ``width_px``, baseline in m."""

    focal_px: float
    width_px: float
    baseline_m: float

    def focal_at(self, width: int) -> float:
        """The focal length (px) for an image ``width`` px wide: rescaled if it is not ``width_px``."""
        return self.focal_px * width / self.width_px


def _read_camera(path: str | os.PathLike) -> Camera:
    """The camera file (YAML: ``focal_px``, ``width_px``, ``baseline_m``, all > 0)."""
    path = Path(path)
    hint = f"no camera file (data.folder.camera: {', '.join(CAMERA_KEYS)})"
    raw = read_data_file(path, "camera file", hint)
    if not isinstance(raw, dict):
        raise DataError(f"{path}: expected a mapping with {', '.join(CAMERA_KEYS)}")
    missing, unknown = set(CAMERA_KEYS) - set(raw), set(raw) - set(CAMERA_KEYS)
    if missing or unknown:
        raise DataError(
            f"{path}: camera file needs exactly {list(CAMERA_KEYS)}; "
            f"missing {sorted(missing)}, unknown {sorted(map(str, unknown))}"
        )
    values = {key: _camera_value(path, key, raw[key]) for key in CAMERA_KEYS}
    return Camera(**values)


def _camera_value(path: Path, key: str, value: object) -> float:
    """``value`` of the camera file's ``key`` as a float; a DataError naming ``path`` unless it is a
    number within :data:`CAMERA_RANGES` (``width_px`` a whole number)."""
    low, high = CAMERA_RANGES[key]
    unit = {"focal_px": "px", "width_px": "px", "baseline_m": "m"}[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise DataError(f"{path}: {key} must be a number ({low:g} to {high:g} {unit}), got {value!r}")
    if not low <= value <= high:
        raise DataError(f"{path}: {key} must be {low:g} to {high:g} {unit}, got {value!r}")
    if key == "width_px" and value != int(value):
        raise DataError(f"{path}: width_px must be a whole number of pixels, got {value!r}")
    return float(value)


def below_root(root: Path, path: str | os.PathLike, where: str, what: str) -> Path:
    """``root / path`` once ``path`` is known to stay below the folder ``root``: a DataError naming
    ``where`` for an absolute path or one whose ``..`` leads out of it. The pipeline tracks the folder
    (``data.root``) in DVC: a file outside it could change without rerunning anything. (Judged on
    the names, so a symbolic link inside the folder stays the user's choice: DVC hashes its target.)

    Example:
        >>> below_root(Path("data/stereo"), "gt/1.pfm", "eval.txt:1", "GT").as_posix()
        'data/stereo/gt/1.pfm'
    """
    rel = os.path.normpath(os.path.relpath(os.path.normpath(Path(root) / path), os.path.normpath(root)))
    if Path(path).is_absolute() or rel == ".." or rel.startswith(".." + os.sep):
        kind = "an absolute path" if Path(path).is_absolute() else "a path out of the folder"
        raise DataError(
            f"{where}: the {what} {os.fspath(path)!r} is {kind}: name files below {root} (DVC tracks only "
            "that folder, so a file outside it could change without rerunning anything)"
        )
    return Path(root) / path


def check_layout(paths: FolderLayout) -> None:
    """A DataError when a ``data.folder.*`` path of ``paths`` (camera, evaluation list, class maps,
    ROI file, pairs list, image folders) is not below the folder (:func:`below_root`)."""
    for key in ("left", "right", "pairs", "camera", "eval_list", "rois_csv", "class_maps"):
        path = getattr(paths, key)
        if path is not None:
            rel = os.path.relpath(os.path.normpath(path), os.path.normpath(paths.root))
            below_root(paths.root, rel, f"data.folder.{key}", "path")


def write_camera(path: str | os.PathLike, camera: Camera) -> None:
    write_text(path, yaml.safe_dump({k: getattr(camera, k) for k in CAMERA_KEYS}, sort_keys=False))


def gt_kind(path: str | os.PathLike, *, npy_is_disparity: bool = False) -> str:
    """The ``gt_kind`` (:data:`msdepth.data.ground_truth.GT_KINDS`) of a GT file, by its suffix."""
    suffix = Path(path).suffix.lower()
    if suffix == ".png":
        return "disparity"
    if suffix == ".pfm":
        return "pfm"
    if suffix == ".npy":
        return "npy_disparity" if npy_is_disparity else "npy_depth"
    raise DataError(
        f"{path}: unknown GT format {suffix or '(no suffix)'!r}: use .png (KITTI disparity), "
        ".pfm (disparity in px) or .npy (depth in m, or disparity with data.folder.npy_is_disparity)"
    )


def _read_eval_list(path: str | os.PathLike, root: Path) -> list[tuple[str, str, str]]:
    """The evaluation list's ``left right [gt]`` lines as (left, right, gt or ""), each file below
    the folder ``root`` (:func:`below_root`)."""
    rows = []
    missing = "no evaluation list (data.folder.eval_list: 'left right [gt]' per line)"
    for number, line, fields in kitti.list_lines(path, missing):
        if len(fields) not in (2, 3):
            raise DataError(f"{path}:{number}: expected 'left right [gt]', got {line.strip()!r}")
        for field_, what in zip(fields, ("left image", "right image", "GT file"), strict=False):
            below_root(root, field_, f"{path}:{number}", what)
        rows.append((fields[0], fields[1], fields[2] if len(fields) == 3 else ""))
    if not rows:
        raise DataError(f"{path}: the evaluation list lists no frame")
    return rows


def _image_files(folder: Path) -> list[Path]:
    """The images below ``folder``, sorted; one whose name :func:`_unlistable` refuses is a DataError
    naming it (and how many others share the problem), in prepare_data and index alike."""
    if not folder.is_dir():
        raise DataError(f"{folder}: no image folder")
    files = sorted(p for p in folder.rglob("*") if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    odd = [p for p in files if _unlistable(p.relative_to(folder))]
    if odd:
        others = f" ({len(odd) - 1} other image(s) too)" if len(odd) > 1 else ""
        raise DataError(
            f"{repr(str(odd[0]))[1:-1]}: {_unlistable(odd[0].relative_to(folder))}: the pipeline's lists "
            f"hold one 'left right' pair per line; rename it{others}"
        )
    return files


def _unlistable(name: Path) -> str:
    """Why an image's relative ``name`` cannot stand in the pipeline's lists, "" if it can: bytes
    that are not UTF-8 (no text file can hold them) or white space (space, tab, newline, carriage
    return: the lists' separators)."""
    text = str(name)
    if any("\udc80" <= c <= "\udcff" for c in text):  # os.fsdecode's escapes of undecodable bytes
        return "a file name that is not UTF-8"
    if any(c.isspace() for c in text):
        return "a file name with white space (space, tab, newline or carriage return)"
    return ""


def _existing(path: Path, what: str) -> Path:
    """``path`` if it is a regular file (or a symbolic link to one); else a DataError naming it and
    what it is (:func:`file_problem`)."""
    problem = file_problem(path, what)
    if problem is not None:
        raise DataError(f"{path}: {problem}")
    return path


def file_problem(path: Path, what: str) -> str | None:
    """What keeps ``path`` from being a readable ``what`` ("no such class map", "a symbolic link to a
    FIFO, not a regular file (class map)", ...), None if it is a regular file or a link to one."""
    link = "a symbolic link to " if os.path.islink(path) else ""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return f"{link}a missing file ({what})" if link else f"no such {what}"
    except OSError as exc:  # a link loop, a name too long, no permission on a folder
        return f"cannot reach this {what} ({exc.strerror or exc})"
    if stat.S_ISREG(mode):
        return None
    kind = "a folder" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode) else "a socket"
    kind = "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else kind
    return f"{link}{kind}, not a regular file ({what})"


def build_train_pairs(paths: FolderLayout) -> tuple[list[tuple[Path, Path]], int]:
    """(training pairs, how many evaluation frames were left out of them).

    The left folder's images with their right namesakes, or ``paths.pairs``'s lines; either way
    without the evaluation list's left images. A missing right (or listed) image is a DataError.
    """
    eval_lefts = {
        (paths.root / left).resolve() for left, _, _ in _read_eval_list(paths.eval_list, paths.root)
    }
    if paths.pairs is None:
        lefts = _image_files(paths.left)
        if not lefts:
            raise DataError(f"{paths.left}: no images ({', '.join(IMAGE_SUFFIXES)})")
        pairs = [(left, paths.right / left.relative_to(paths.left)) for left in lefts]
        lonely = [(left, right) for left, right in pairs if not right.is_file()]
        if lonely:
            left, right = lonely[0]
            raise DataError(
                f"{right}: no right image for {left} ({len(lonely)} of {len(pairs)} left images lack "
                f"their namesake in {paths.right})"
            )
    else:
        pairs = [
            (
                _existing(below_root(paths.root, left, str(paths.pairs), "left image"), "left image"),
                _existing(below_root(paths.root, right, str(paths.pairs), "right image"), "right image"),
            )
            for left, right in kitti.read_split(paths.pairs)
        ]
    train = [(left, right) for left, right in pairs if left.resolve() not in eval_lefts]
    if not train:
        raise DataError(
            f"{paths.pairs or paths.left}: no training pair left once the {len(eval_lefts)} evaluation "
            f"frames of {paths.eval_list} are taken out"
        )
    return train, len(pairs) - len(train)


def _same_size(left: Path, shape: tuple, other: Path, other_shape: tuple, what: str) -> None:
    # As msdepth.data.pairs.check_same_size, which would make the prepare_data stage import torch.
    if tuple(shape[:2]) != tuple(other_shape[:2]):
        raise DataError(f"{left} is {tuple(shape[:2])} but its {what} {other} is {tuple(other_shape[:2])}")


def eval_rows(
    paths: FolderLayout, camera: Camera | None = None, *, npy_is_disparity: bool = False
) -> list[tuple]:
    """One row of :data:`msdepth.data.eval_index.EVAL_COLUMNS` per evaluation frame (the DataFrame:
    :func:`msdepth.data.eval_sets.folder_eval_index`): the images, the GT and its kind (by
    suffix; ``none`` without GT), the camera at the image's width, no crop, the class map if
    ``paths.class_maps``. Each GT and class map is read once here, so a bad file fails the index
    stage, not the evaluation."""
    check_layout(paths)
    camera = camera or _read_camera(paths.camera)
    classes = read_classes(paths.class_maps / CLASSES_FILE) if paths.class_maps else None
    rows, names = [], {}
    for left_rel, right_rel, gt_rel in _read_eval_list(paths.eval_list, paths.root):
        left = _existing(paths.root / left_rel, f"left image (listed in {paths.eval_list})")
        right = _existing(paths.root / right_rel, f"right image (listed in {paths.eval_list})")
        name = left.stem
        if name in names:
            raise DataError(
                f"{paths.eval_list}: {left} and {names[name]} share the frame name {name!r} "
                "(the left image's file stem): rename one"
            )
        names[name] = left
        shape = kitti.read_image(left).shape
        _same_size(left, shape, right, kitti.read_image(right).shape, "right image")
        focal, baseline = camera.focal_at(shape[1]), camera.baseline_m
        if gt_rel:
            gt = _existing(paths.root / gt_rel, f"GT file (listed in {paths.eval_list})")
            kind = gt_kind(gt, npy_is_disparity=npy_is_disparity)
            depth = read_gt_depth(kind, gt, focal=focal, baseline=baseline)
            _same_size(left, shape, gt, depth.shape, "GT")
        else:
            gt, kind = left, "none"
        class_map = ""
        if classes is not None:
            what = f"class map of frame {name!r} (data.folder.class_maps)"
            class_map = _existing(paths.class_maps / f"{name}.png", what)
            _same_size(left, shape, class_map, read_label_class_map(class_map, classes).shape, "class map")
        rows.append((name, str(left), str(right), str(gt), kind, "", "", "", str(class_map), focal, baseline))
    return rows


def check_folder(paths: FolderLayout) -> dict:
    """What the ``prepare_data`` stage checks: the folder holds what the layout needs (images,
    right namesakes, camera, evaluation list and the files it names). One DataError listing every
    problem found; nothing is written. Returns counts for the log."""
    if not paths.root.is_dir():
        raise DataError(
            f"{paths.root}: no such folder (data.root, with data.source folder: the stereo folder; "
            "see docs/user-guide.md 'Train and evaluate on your own stereo camera')"
        )
    check_layout(paths)
    problems, report = [], {}
    for what, check in (
        ("camera", lambda: _read_camera(paths.camera)),
        ("evaluation list", lambda: _read_eval_list(paths.eval_list, paths.root)),
        ("classes", lambda: read_classes(paths.class_maps / CLASSES_FILE) if paths.class_maps else None),
    ):
        try:
            report[what] = check()
        except DataError as exc:
            problems.append(str(exc))
    if "evaluation list" in report:
        for left, right, gt in report["evaluation list"]:
            for rel in (left, right, gt):
                if rel and (problem := file_problem(paths.root / rel, "file")) is not None:
                    problem = "missing" if problem == "no such file" else problem
                    problems.append(f"{paths.root / rel}: listed in {paths.eval_list} but {problem}")
            class_map = paths.class_maps / f"{Path(left).stem}.png" if paths.class_maps else None
            if class_map and (problem := file_problem(class_map, "class map")) is not None:
                problem = "no class map" if problem == "no such class map" else problem
                problems.append(f"{class_map}: {problem} for {left} (data.folder.class_maps)")
        try:
            train, excluded = build_train_pairs(paths)
            report["train_pairs"], report["eval_frames_excluded"] = len(train), excluded
        except DataError as exc:
            problems.append(str(exc))
    if paths.rois_csv is not None and not paths.rois_csv.is_file():
        problems.append(f"{paths.rois_csv}: no such ROI file (data.folder.rois_csv)")
    if problems:
        shown = "; ".join(problems[:5]) + (f"; and {len(problems) - 5} more" if len(problems) > 5 else "")
        raise DataError(f"{paths.root}: not a usable stereo folder (data.source folder): {shown}")
    return {
        "train_pairs": report["train_pairs"],
        "eval_frames": len(report["evaluation list"]),
        "eval_frames_with_gt": sum(1 for *_, gt in report["evaluation list"] if gt),
    }
