"""Regions of interest on the KITTI 2015 evaluation frames: car boxes from ``obj_map``, plus hand-drawn boxes.

KITTI 2015 ships an ``obj_map`` per training frame (uint8 car instance ids, 0 = background), so
the car boxes of the ROI suite can be derived instead of drawn: one tight box per instance. The
dissertation's other boxes (windshields, glass, signs, and any cars drawn by hand) come in as a
user CSV in the ROI format of :func:`msdepth.data.kitti.read_rois` and are checked against the
evaluation frames before they are merged. :func:`_contact_sheet` renders the crops on one image,
to see at a glance that the boxes land on the objects.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pandas as pd

from msdepth.config.params import Params
from msdepth.data import kitti
from msdepth.data.layout import folder_layout, layout
from msdepth.errors import DataError
from msdepth.io import write_png

log = logging.getLogger(__name__)

Box = tuple[int, int, int, int, int]  # (instance id, x0, y0, x1, y1), x1/y1 exclusive

# Contact-sheet layout (pixels). Public so that callers and tests can size a sheet.
PAD = 2  # border around each crop inside its cell
LABEL_HEIGHT = 26  # two text lines under each crop
HEADER_HEIGHT = 26  # one strip naming the class above its crops (with a gap above the text)

_BACKGROUND = (24, 24, 24)
_LETTERBOX = (64, 64, 64)  # lighter than the background: the crop's own extent stays visible
_TEXT = (235, 235, 235)
_CLASS_COLOURS = {  # RGB; distinct at a glance in the headers and the labels
    "car": (255, 170, 60),
    "windshield": (90, 200, 255),
    "glass": (150, 255, 150),
    "sign": (255, 110, 200),
}
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_LABEL_SCALE = 0.36  # Hershey below ~0.3 is no longer legible
_MIN_SCALE = 0.3


def _boxes_from_obj_map(
    obj_map: np.ndarray, gt_disp: np.ndarray, *, min_size: int = 16, min_valid: float = 0.3
) -> list[Box]:
    """One tight box per instance id > 0 of ``obj_map``, as ``(id, x0, y0, x1, y1)`` sorted by id.

    A box is kept only if both its sides are at least ``min_size`` px and at least ``min_valid``
    of its pixels have ground truth (``gt_disp > 0``): metrics inside a tiny or GT-less box would
    be noise. Ids need not be contiguous.
    """
    if min_size < 1:
        raise ValueError(f"min_size must be >= 1, got {min_size}")
    if not 0.0 <= min_valid <= 1.0:
        raise ValueError(f"min_valid must be in [0, 1], got {min_valid}")
    obj_map, gt_disp = np.asarray(obj_map), np.asarray(gt_disp)
    if obj_map.ndim != 2 or not np.issubdtype(obj_map.dtype, np.integer):
        raise DataError(
            f"object map must be a 2-D integer array, got {obj_map.dtype} of shape {obj_map.shape}"
        )
    if gt_disp.shape != obj_map.shape:
        raise DataError(f"object map is {obj_map.shape} but its GT disparity is {gt_disp.shape}")
    valid = gt_disp > 0  # NaN compares False: no GT
    boxes: list[Box] = []
    for instance in np.unique(obj_map[obj_map > 0]):
        mask = obj_map == instance
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        y0, y1, x0, x1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
        if x1 - x0 < min_size or y1 - y0 < min_size:
            continue
        # The fraction over the whole box, not the instance's pixels: the ROI metrics use the box.
        if valid[y0:y1, x0:x1].mean() < min_valid:
            continue
        boxes.append((int(instance), x0, y0, x1, y1))
    return boxes


def _empty_rois() -> pd.DataFrame:
    """An ROI table with no rows but the right columns and dtypes."""
    return pd.DataFrame(
        {
            "image": pd.Series(dtype=str),
            "class": pd.Series(dtype=str),
            **{c: pd.Series(dtype=np.int64) for c in ("x0", "y0", "x1", "y1")},
        }
    )


def _image_size(path: str) -> tuple[int, int]:
    """``(height, width)`` of an image file (decoded by the KITTI reader, so errors name it)."""
    return kitti.read_image(path).shape[:2]


def _check_user_rois(user_csv: Path, frames: pd.DataFrame) -> pd.DataFrame:
    """The user CSV's rows, after checking each names an evaluation frame and fits in its image."""
    user = kitti.read_rois(user_csv)  # format, classes and box sanity, with CSV line numbers
    lefts = dict(zip(frames["frame"].astype(str), frames["left"].astype(str), strict=True))
    sizes: dict[str, tuple[int, int]] = {}
    for i, row in enumerate(user.itertuples(index=False), start=2):  # line numbers as read_rois
        image = row.image
        if image not in lefts:
            hint = f" (did you mean {Path(image).stem!r}?)" if Path(image).stem in lefts else ""
            raise DataError(
                f"{user_csv}: row {i}: image {image!r} is not an evaluation frame{hint}; "
                f"frames look like {sorted(lefts)[:3]}"
            )
        if image not in sizes:
            sizes[image] = _image_size(lefts[image])
        h, w = sizes[image]
        if row.x1 > w or row.y1 > h:
            raise DataError(
                f"{user_csv}: row {i}: box ({row.x0}, {row.y0}, {row.x1}, {row.y1}) lies outside "
                f"frame {image}'s {w}x{h} image (x1 <= {w} and y1 <= {h}, exclusive)"
            )
    return user


def _car_rows(
    frame: Any, min_size: int, min_valid: float
) -> list[tuple[str, str, int, int, int, int]] | None:
    """The ROI rows of the car boxes of ``frame`` (a row of the evaluation index's ``itertuples()``);
    None if it has no ``obj_map``."""
    name = str(frame.frame)
    obj_path = frame.obj_map if isinstance(frame.obj_map, str) else ""  # NaN from a bare read_csv
    if not obj_path:
        return None
    if frame.gt_kind != "disparity":
        raise DataError(
            f"{name}: car boxes need a KITTI 2015 disparity GT, got {frame.gt_kind!r} ({frame.gt})"
        )
    obj_map = kitti.read_obj_map(obj_path)
    gt = kitti.read_disparity(frame.gt)
    try:
        boxes = _boxes_from_obj_map(obj_map, gt, min_size=min_size, min_valid=min_valid)
    except DataError as exc:
        raise DataError(f"{obj_path}: {exc} ({frame.gt})") from None
    return [(name, "car", x0, y0, x1, y1) for _, x0, y0, x1, y1 in boxes]


def _merge_rois(auto: pd.DataFrame, user: pd.DataFrame) -> pd.DataFrame:
    """``auto`` and ``user`` as one ROI table without exact duplicates, sorted by ROI_COLUMNS."""
    parts = [p for p in (auto, user) if len(p)]  # concat with an empty frame would loosen the dtypes
    rois = pd.concat(parts, ignore_index=True) if parts else _empty_rois()
    rois = rois.drop_duplicates().astype({c: np.int64 for c in ("x0", "y0", "x1", "y1")})
    return rois.sort_values(list(kitti.ROI_COLUMNS), kind="stable").reset_index(drop=True)


def _report(
    frames: pd.DataFrame, without: list[str], auto: pd.DataFrame, user: pd.DataFrame, rois: pd.DataFrame
) -> dict:
    """:func:`_extract_rois`' summary (frame and box counts), logged as well."""
    report = {
        "frames": len(frames),
        "frames_without_obj_map": len(without),
        "car_boxes_from_obj_map": len(auto),
        "user_boxes": len(user),
        "rois": len(rois),
        "per_class": {c: int((rois["class"] == c).sum()) for c in kitti.ROI_CLASSES},
    }
    if without:
        log.info(
            "%d of %d evaluation frame(s) have no obj_map (no car boxes): %s%s",
            len(without),
            len(frames),
            without[:5],
            " ..." if len(without) > 5 else "",
        )
    log.info("ROIs: %d (%s)", len(rois), ", ".join(f"{c} {n}" for c, n in report["per_class"].items()))
    return report


def _extract_rois(
    frames: pd.DataFrame,
    *,
    user_csv: Path | None = None,
    min_size: int = 16,
    min_valid: float = 0.3,
    progress: bool = True,
) -> pd.DataFrame:
    """The ROI table of the evaluation frames: automatic car boxes plus the user CSV's boxes.

    ``frames`` is the evaluation index (:func:`msdepth.data.eval_index.read_eval_index`): every frame
    with an ``obj_map`` gives its car boxes (:func:`_boxes_from_obj_map` against the frame's GT);
    frames without one give none. Rows of ``user_csv`` are validated (evaluation frame, inside
    the image) and merged; exact duplicates are dropped, so re-feeding an earlier output is
    harmless. Returns ROI_COLUMNS sorted by image, class, x0, y0 (possibly empty). A summary
    (frame counts, box counts) is logged and left in ``result.attrs["report"]``.
    """
    from tqdm import tqdm

    missing = {"frame", "left", "gt", "gt_kind", "obj_map"} - set(frames.columns)
    if missing:
        raise DataError(f"evaluation index: missing columns {sorted(missing)}")
    rows: list[tuple[str, str, int, int, int, int]] = []
    without: list[str] = []
    for frame in tqdm(
        frames.itertuples(index=False), total=len(frames), desc="rois", unit="frame", disable=not progress
    ):
        cars = _car_rows(frame, min_size, min_valid)
        if cars is None:
            without.append(str(frame.frame))
        else:
            rows += cars
    auto = pd.DataFrame(rows, columns=list(kitti.ROI_COLUMNS)) if rows else _empty_rois()
    user = _check_user_rois(Path(user_csv), frames) if user_csv is not None else _empty_rois()
    rois = _merge_rois(auto, user)
    rois.attrs["report"] = _report(frames, without, auto, user, rois)
    return rois


def _pipeline_rois(params: Params, frames: pd.DataFrame) -> pd.DataFrame:
    """The ROI boxes of the evaluation frames ``frames`` (the evaluation index): the synthetic set's
    exact ones, KITTI's obj_map cars plus the user's CSV, or a stereo folder's data.folder.rois_csv.
    No ROI at all is allowed (warned: the ROI suites then say they were skipped)."""
    if params.data.source == "folder":  # the user's boxes only: a folder has no obj_map
        boxes = _extract_rois(frames, user_csv=folder_layout(params).rois_csv)
    elif (source := layout(params).rois) is not None:
        boxes = kitti.read_rois(source)
        unknown = sorted(set(boxes["image"]) - set(frames["frame"]))
        if unknown:
            raise DataError(f"{source}: boxes name images that are not evaluation frames: {unknown[:10]}")
    else:  # _extract_rois checks the user's boxes against the frames itself
        k = params.data.kitti
        boxes = _extract_rois(
            frames,
            user_csv=_optional_path(k.rois_csv),
            min_size=k.roi_min_size,
            min_valid=k.roi_min_valid,
        )
    if boxes.empty:  # the ROI suites then write an explicit "no ROIs" summary
        log.warning(
            "rois: no ROI (%s): the ROI and gradient suites will be skipped",
            "no data.folder.rois_csv"
            if params.data.source == "folder"
            else "no car in any obj_map passed data.kitti.roi_min_size/roi_min_valid, "
            "and no data.kitti.rois_csv",
        )
    return boxes


def write_roi_index(params: Params, frames: pd.DataFrame, out: Path, sheet: Path) -> pd.DataFrame:
    """:func:`_pipeline_rois` of ``frames`` written as the ROI index ``out`` and its
    :func:`_contact_sheet` ``sheet``; returns the boxes."""
    boxes = _pipeline_rois(params, frames)
    kitti.write_rois(out, boxes)
    _contact_sheet(boxes, frames, sheet)
    log.info("rois: %d boxes, %s", len(boxes), boxes["class"].value_counts().to_dict())
    return boxes


def _optional_path(value: str) -> Path | None:
    return Path(value) if value else None


def set_roi_boxes(params: Params, name: str, frames: pd.DataFrame) -> pd.DataFrame:
    """The ROI boxes of extra set ``name`` (a key of ``eval.extra_sets``; ``frames``, its evaluation
    index): ``kitti2015``, the obj_map cars (``data.kitti.roi_min_size``/``roi_min_valid``) plus
    ``data.kitti.rois_csv``'s boxes, as on KITTI 2015's evaluation frames; ``kitti2012``, which has
    no obj_map, ``data.kitti.kitti2012_rois_csv``'s; ``folder``, ``data.folder.rois_csv``'s; none on
    the Eigen sets (no object annotation).
    A user box must name one of the set's frames and fit its image (:func:`_extract_rois`).

    Example:
        >>> from msdepth.config.params import Params
        >>> frames = pd.DataFrame({"frame": ["a"], "left": ["a.png"], "gt": ["a.bin"],
        ...                        "gt_kind": ["velodyne"], "obj_map": [""]})
        >>> len(set_roi_boxes(Params(), "eigen", frames))
        0
    """
    k = params.data.kitti
    if name == "kitti2015":
        user = _optional_path(k.rois_csv)
        return _extract_rois(
            frames, user_csv=user, min_size=k.roi_min_size, min_valid=k.roi_min_valid, progress=False
        )
    if name == "kitti2012":
        return _extract_rois(frames, user_csv=_optional_path(k.kitti2012_rois_csv), progress=False)
    if name == "folder":
        return _extract_rois(frames, user_csv=folder_layout(params).rois_csv, progress=False)
    return _empty_rois()


def write_set_rois(params: Params, name: str, frames: pd.DataFrame, out: Path) -> pd.DataFrame:
    """:func:`set_roi_boxes` of set ``name`` written as the ROI file ``out`` and its contact sheet
    (``out`` with ``.png``); returns the boxes."""
    boxes = set_roi_boxes(params, name, frames)
    kitti.write_rois(out, boxes)
    _contact_sheet(boxes, frames, out.with_suffix(".png"))
    log.info("rois of set %s: %d boxes, %s", name, len(boxes), boxes["class"].value_counts().to_dict())
    return boxes


# --------------------------------------------------------------------------------------------
# Contact sheet


def _fit_scale(text: str, width: int, scale: float, thickness: int = 1) -> float:
    """The largest font scale <= ``scale`` (down to the legible minimum) at which ``text`` fits ``width``."""
    text_w = cv2.getTextSize(text, _FONT, scale, thickness)[0][0]
    return max(_MIN_SCALE, scale * min(1.0, width / max(text_w, 1)))


def _put(
    img: np.ndarray,
    text: str,
    x: int,
    baseline: int,
    width: int,
    colour: tuple[int, int, int],
    scale: float = _LABEL_SCALE,
) -> None:
    """Draw ``text`` at ``(x, baseline)``, shrunk to fit ``width``, anti-aliased."""
    cv2.putText(img, text, (x, baseline), _FONT, _fit_scale(text, width, scale), colour, 1, cv2.LINE_AA)


def _letterbox(crop: np.ndarray, tile: int) -> np.ndarray:
    """``crop`` scaled to fit a ``tile`` x ``tile`` square (aspect kept), centred on a grey field."""
    h, w = crop.shape[:2]
    scale = tile / max(h, w)
    nh, nw = max(1, round(h * scale)), max(1, round(w * scale))
    # Area averaging when shrinking (no aliasing); nearest when enlarging, so the pixels the box
    # really covers stay visible instead of being smoothed into a blur.
    interp = cv2.INTER_AREA if scale < 1 else cv2.INTER_NEAREST
    resized = cv2.resize(crop, (nw, nh), interpolation=interp)
    cell = np.empty((tile, tile, 3), np.uint8)
    cell[:] = _LETTERBOX
    y, x = (tile - nh) // 2, (tile - nw) // 2
    cell[y : y + nh, x : x + nw] = resized
    return cell


def _pick(group: pd.DataFrame, limit: int) -> pd.DataFrame:
    """At most ``limit`` rows, spread evenly over the group (so many frames show, not the first few)."""
    if len(group) <= limit:
        return group
    return group.iloc[np.linspace(0, len(group) - 1, limit).round().astype(int)]


@dataclass(frozen=True)
class _Sheet:
    """A contact sheet's layout and where its crops come from."""

    out_path: Path  # named in errors
    lefts: dict[str, str]  # frame -> left image path
    tile: int
    columns: int

    @property
    def cell(self) -> tuple[int, int]:
        """A cell's (width, height): the crop with its border, plus the label strip below."""
        return self.tile + 2 * PAD, self.tile + LABEL_HEIGHT + 2 * PAD

    @property
    def width(self) -> int:
        """The sheet's width in pixels."""
        return self.columns * self.cell[0]


def _class_order(rois: pd.DataFrame) -> list[str]:
    """Known classes in their canonical order, then anything else a caller passes, alphabetically."""
    present = list(dict.fromkeys(rois["class"])) if len(rois) else []
    return [c for c in kitti.ROI_CLASSES if c in present] + sorted(
        c for c in present if c not in kitti.ROI_CLASSES
    )


def _header_block(
    sheet: _Sheet, rows: int, text: str, colour: tuple[int, int, int], *, underline: bool
) -> np.ndarray:
    """A block of ``rows`` cell rows under a header strip reading ``text``, underlined or not."""
    block = np.empty((HEADER_HEIGHT + rows * sheet.cell[1], sheet.width, 3), np.uint8)
    block[:] = _BACKGROUND
    if underline:  # class blocks stay apart at a glance
        block[HEADER_HEIGHT - 2 : HEADER_HEIGHT] = colour
    _put(block, text, 6, HEADER_HEIGHT - 8, sheet.width - 12, colour, 0.5)
    return block


def _crop(sheet: _Sheet, roi: Any, images: dict[str, np.ndarray]) -> np.ndarray:
    """The pixels of ``roi`` (a row of the ROI table) in its left image, decoded once into ``images``."""
    name = str(roi.image)
    if name not in sheet.lefts:
        raise DataError(f"{sheet.out_path}: ROI image {name!r} is not in the evaluation index")
    if name not in images:
        images[name] = kitti.read_image(sheet.lefts[name])
    img = images[name]
    h, w = img.shape[:2]
    x0, y0, x1, y1 = int(roi.x0), int(roi.y0), int(roi.x1), int(roi.y1)
    if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
        raise DataError(
            f"{sheet.out_path}: ROI ({x0}, {y0}, {x1}, {y1}) lies outside {sheet.lefts[name]} ({w}x{h})"
        )
    return img[y0:y1, x0:x1]


def _class_block(
    sheet: _Sheet, cls: str, group: pd.DataFrame, max_per_class: int, images: dict[str, np.ndarray]
) -> np.ndarray:
    """One class's block: its header strip over its letterboxed, labelled crops."""
    shown = _pick(group, max_per_class)
    (cell_w, cell_h), tile = sheet.cell, sheet.tile
    colour = _CLASS_COLOURS.get(cls, _TEXT)
    block = _header_block(
        sheet,
        -(-len(shown) // sheet.columns),
        f"{cls}: {len(shown)} shown of {len(group)}",
        colour,
        underline=True,
    )
    for k, roi in enumerate(shown.itertuples(index=False)):
        crop = _crop(sheet, roi, images)
        top = HEADER_HEIGHT + (k // sheet.columns) * cell_h
        left = (k % sheet.columns) * cell_w
        block[top + PAD : top + PAD + tile, left + PAD : left + PAD + tile] = _letterbox(crop, tile)
        text_y = top + PAD + tile
        _put(block, f"{cls} {crop.shape[1]}x{crop.shape[0]}", left + PAD + 1, text_y + 11, tile - 2, colour)
        _put(block, str(roi.image), left + PAD + 1, text_y + 23, tile - 2, _TEXT)
    return block


def _contact_sheet(
    rois: pd.DataFrame,
    frames: pd.DataFrame,
    out_path: Path,
    *,
    tile: int = 96,
    columns: int = 8,
    max_per_class: int = 16,
) -> Path:
    """Write a PNG grid of ROI crops from the left images, one block per class, and return its path.

    Each block is a header strip (class, boxes shown of total) over rows of ``columns`` cells;
    a cell is the crop letterboxed into ``tile`` x ``tile`` px with the class, box size and frame
    written under it. Up to ``max_per_class`` crops per class, spread over the class's boxes.
    Sheet size: width ``columns * (tile + 2 * PAD)``; height the sum over shown classes of
    ``HEADER_HEIGHT + ceil(n / columns) * (tile + LABEL_HEIGHT + 2 * PAD)`` (just a header when
    there are no ROIs).
    """
    if tile < 8 or columns < 1 or max_per_class < 1:
        raise ValueError(
            f"need tile >= 8, columns >= 1, max_per_class >= 1; got {tile}, {columns}, {max_per_class}"
        )
    out_path = Path(out_path)
    lefts = dict(zip(frames["frame"].astype(str), frames["left"].astype(str), strict=True))
    sheet = _Sheet(out_path, lefts, tile, columns)
    images: dict[str, np.ndarray] = {}  # each left image decoded once
    blocks = [
        _class_block(
            sheet,
            cls,
            rois[rois["class"] == cls].sort_values(["image", "x0", "y0"], kind="stable"),
            max_per_class,
            images,
        )
        for cls in _class_order(rois)
    ]
    if not blocks:  # still an image, so that a pipeline output exists and says why it is empty
        blocks.append(_header_block(sheet, 0, "no ROIs", _TEXT, underline=False))
    write_png(out_path, np.concatenate(blocks, axis=0))
    return out_path
