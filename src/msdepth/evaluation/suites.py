"""The three evaluation suites: full image, ROI crops, gradient consistency on ROIs.

Every suite reads the same inputs whatever the evaluation set: predicted depth per frame (from
:func:`depth_maps`), the frames (:class:`Frame`: GT depth, camera, crop) and, for the ROI suites,
the ROI boxes. Metrics are computed per image (or per ROI) with
:func:`msdepth.evaluation.metrics.compute_errors` (the full image also with
:func:`~msdepth.evaluation.metrics.stereo_errors`, D1 and EPE), then averaged, for each depth cap.
Frames or ROIs without valid GT are excluded and counted.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np
import pandas as pd

from msdepth.config.params import EvalConfig
from msdepth.data import kitti
from msdepth.data.ground_truth import read_frame_classes, read_gt_depth
from msdepth.errors import DataError
from msdepth.evaluation.metrics import (
    METRICS,
    STEREO_METRICS,
    compute_errors,
    garg_crop_mask,
    median_scale,
    stereo_errors,
)
from msdepth.geometry.depth import (
    clamp_depth,
    depth_to_disparity,
    disparity_to_depth,
    pixel_disparity,
    predicted_depth,
)
from msdepth.pipeline.paths import ROIS
from msdepth.readers import read_npz_file

GRADIENTS = ("sobel_x", "sobel_y", "laplacian")
# The summary key of an ROI or gradient suite run without any ROI (a folder without
# data.folder.rois_csv, KITTI without obj_map or CSV): {"rois": 0, NO_ROIS: why}, no caps. Not
# "skipped": that key marks a baseline that could not be built (msdepth.evaluation.baselines.SKIPPED).
NO_ROIS = "no_rois"
NO_ROIS_REASON = f"no ROIs: the ROI index ({ROIS.as_posix()}) is empty, so this suite was skipped"
ROI_COLUMNS = ("roi", "image", "class", "cap", *METRICS)
GRADIENT_COLUMNS = ("roi", "image", "class", "cap", *(f"pred_{g}" for g in GRADIENTS), "gt_valid_fraction")


def no_rois(summary: dict) -> bool:
    """Whether a suite summary is the explicit "no ROIs" one."""
    return NO_ROIS in summary


def _no_roi_result(columns: tuple[str, ...]) -> tuple[dict, pd.DataFrame]:
    """The summary and header-only table of an ROI suite with no ROI to evaluate."""
    return {"rois": 0, NO_ROIS: NO_ROIS_REASON}, pd.DataFrame(columns=list(columns))


CROPS = {"garg": garg_crop_mask}  # the index's ``crop`` column -> the mask of a frame size


@dataclass(frozen=True)
class Frame:
    """One evaluation frame of any set: GT depth, its camera, and how its set evaluates it.

    ``gt_depth`` is in metres, 0 = no GT (KITTI 2015's disparity becomes depth when it is read).
    ``crop``: the pixels evaluated (the Eigen split's Garg crop), None = all. ``gt_in_range``:
    GT outside (min_depth, cap) is left out, as the Eigen evaluation does; KITTI 2015's keeps it
    (``eval.mask_gt_beyond_cap`` can ask for it there).
    """

    name: str
    gt_depth: np.ndarray
    focal: float
    baseline: float
    class_map: np.ndarray | None = None  # bits of kitti.CLASS_BITS (ground_truth.read_frame_classes)
    crop: np.ndarray | None = None
    gt_in_range: bool = False
    # The full-image suite scores class_map's classes over the whole frame (evaluation.classes):
    # every set's but the synthetic set's, whose classes the ROI suite scores inside exact boxes.
    whole_frame_classes: bool = False

    @classmethod
    def from_disparity(cls, name: str, gt_disp: np.ndarray, focal: float, baseline: float, **kw) -> Frame:
        """A frame whose GT is a disparity map (pixels, 0 = invalid), as KITTI 2015's."""
        return cls(name, disparity_to_depth(gt_disp, focal, baseline), focal, baseline, **kw)

    @property
    def shape(self) -> tuple[int, int]:
        return self.gt_depth.shape

    @cached_property
    def valid(self) -> np.ndarray:
        """Pixels with GT inside the crop."""
        valid = self.gt_depth > 0
        return valid & self.crop if self.crop is not None else valid


def load_frames(index: pd.DataFrame) -> list[Frame]:
    """Read the GT of every row of an evaluation index (any set: :mod:`msdepth.data.eval_index`)."""
    frames = []
    for row in index.itertuples():
        focal, baseline = float(row.focal), float(row.baseline)
        depth = read_gt_depth(row.gt_kind, row.gt, calib=row.calib, focal=focal, baseline=baseline)
        if row.crop and row.crop not in CROPS:
            raise DataError(
                f"evaluation frame {row.frame}: unknown crop {row.crop!r}; known: {sorted(CROPS)}"
            )
        class_map, whole_frame = read_frame_classes(row.gt_kind, row.class_map, row.obj_map)
        frames.append(
            Frame(
                row.frame,
                depth,
                focal,
                baseline,
                class_map,
                CROPS[row.crop](*depth.shape) if row.crop else None,
                gt_in_range=bool(row.crop),
                whole_frame_classes=whole_frame,
            )
        )
    return frames


def depth_maps(
    disparities: np.ndarray, frames: list[Frame], monocular: bool = False
) -> dict[str, np.ndarray]:
    """Network disparities (N, h, w; fraction of width) -> depth (m) at each frame's GT size.

    ``monocular`` (a model trained with train.mode mono or mono_stereo): the disparity, resized,
    is read as training reads it, Monodepth2's sigmoid disparity (divided by the heads' maximum),
    and turned into Monodepth2's depth (:func:`msdepth.geometry.camera.disp_to_depth`), up to scale:
    such depth is evaluated median-scaled.
    """
    if len(disparities) != len(frames):
        raise DataError(f"{len(disparities)} predicted disparities for {len(frames)} evaluation frames")
    out = {}
    for disp, frame in zip(disparities, frames, strict=True):
        h, w = frame.shape
        if monocular:
            from msdepth.geometry.camera import disp_to_depth  # torch: only for monocular models
            from msdepth.networks.common import MAX_DISPARITY

            sigmoid = pixel_disparity(disp, h, w) / (w * MAX_DISPARITY)
            out[frame.name] = disp_to_depth(sigmoid.astype(np.float32))[1].astype(np.float32)
        else:
            out[frame.name] = predicted_depth(pixel_disparity(disp, h, w), frame.focal, frame.baseline)
    return out


def _metrics_in(
    frame: Frame,
    pred: np.ndarray,
    mask: np.ndarray,
    cap: float,
    cfg: EvalConfig,
    box: tuple[slice, slice] | None = None,
    scale: bool = False,
    stereo: bool = False,
) -> dict | None:
    """The 7 metrics of ``pred`` against ``frame``'s GT on ``mask`` (``pred`` and ``mask`` already
    cropped to ``box``). ``scale``: the prediction is median-scaled first (per image, as
    Monodepth2's monocular evaluation) and the ratio returned as ``ratio``. ``stereo``: KITTI's D1
    and EPE too (:data:`~msdepth.evaluation.metrics.STEREO_METRICS`), on the disparities f·B/depth of
    the same capped prediction and the GT (KITTI 2015's GT disparity back; LiDAR depth's)."""
    gt = frame.gt_depth if box is None else frame.gt_depth[box]
    mask = _evaluated(frame, gt, mask, cap, cfg)
    if not mask.any():
        return None
    gt, pred = gt[mask], pred[mask]
    ratio = None
    if scale:
        pred, ratio = median_scale(gt, pred)
    pred = clamp_depth(pred, cfg.min_depth, cap)
    metrics = compute_errors(gt, pred)
    if stereo:
        camera = (frame.focal, frame.baseline)
        metrics.update(stereo_errors(depth_to_disparity(gt, *camera), depth_to_disparity(pred, *camera)))
    return metrics if ratio is None else {**metrics, "ratio": ratio}


def _evaluated(frame: Frame, gt: np.ndarray, mask: np.ndarray, cap: float, cfg: EvalConfig) -> np.ndarray:
    """``mask`` less the GT pixels that the evaluation at ``cap`` leaves out (``gt``: the frame's
    GT, cropped as ``mask``)."""
    if cfg.mask_gt_beyond_cap:
        mask = mask & (gt <= cap)
    if frame.gt_in_range:
        mask = mask & (gt > cfg.min_depth) & (gt < cap)
    return mask


def median_scaled_maps(
    pred: dict[str, np.ndarray], frames: list[Frame], cfg: EvalConfig
) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """Every frame's prediction median-scaled (:func:`msdepth.evaluation.metrics.median_scale`) over the
    pixels the full-image suite evaluates at the first cap, and the ratios by frame: what a monocular
    (up-to-scale) model's ROI suites and image dependence see. A frame without evaluated GT keeps
    its prediction and gets no ratio."""
    scaled, ratios = {}, {}
    for f in frames:
        mask = _evaluated(f, f.gt_depth, f.valid, cfg.caps[0], cfg)
        if mask.any():
            ratios[f.name] = median_scale(f.gt_depth[mask], pred[f.name][mask])[1]
            scaled[f.name] = pred[f.name] * np.float32(ratios[f.name])
        else:
            scaled[f.name] = pred[f.name]
    return scaled, ratios


def _mean(rows: list[dict], keys: tuple[str, ...]) -> dict[str, float]:
    return {k: float(np.mean([r[k] for r in rows])) for k in keys}


def evaluate_full(
    pred: dict[str, np.ndarray], frames: list[Frame], cfg: EvalConfig, *, median_scaling: bool = False
) -> tuple[dict, pd.DataFrame]:
    """Suite 1: the 7 metrics per image over valid GT, and KITTI's D1 and EPE on the disparity
    f·B/depth of the capped prediction against the GT's (:func:`_metrics_in`), then averaged, per cap.

    ``median_scaling``: each prediction is first scaled by median(GT) / median(prediction) over
    its evaluated pixels (Monodepth2's monocular evaluation); the ratios' median and relative
    spread are reported per cap.
    """
    rows = []
    summary: dict = {}
    for cap in cfg.caps:
        per_cap = []
        for f in frames:
            m = _metrics_in(f, pred[f.name], f.valid, cap, cfg, scale=median_scaling, stereo=True)
            if m is not None:
                per_cap.append({"frame": f.name, "cap": cap, **m})
        if not per_cap:
            raise DataError("full-image evaluation: no frame has valid ground truth")
        summary[f"cap{cap:g}"] = _mean(per_cap, METRICS + STEREO_METRICS)
        if median_scaling:
            ratios = np.array([r["ratio"] for r in per_cap])
            med = float(np.median(ratios))
            summary[f"cap{cap:g}"]["median_scaling"] = {
                "ratio_median": med,
                "ratio_std_over_median": float(ratios.std() / med),
            }
        rows += per_cap
    summary["images"] = len(frames)
    summary["excluded_images"] = len(frames) - len(rows) // len(cfg.caps)
    # Up-to-scale predictions are compared across images once each is median-scaled.
    varied = median_scaled_maps(pred, frames, cfg)[0] if median_scaling else pred
    summary["image_dependence"] = image_dependence(varied, frames, cfg.caps[0])
    return summary, pd.DataFrame(rows)


def image_dependence(
    pred: dict[str, np.ndarray], frames: list[Frame], cap: float, min_frames: int = 3
) -> dict:
    """How much the predictions change from image to image, against how much the GT does.

    Every frame's predicted and GT depth (capped at ``cap``; GT 0 = invalid) are resampled to
    the smallest frame's grid (nearest, so invalid GT stays invalid). At each pixel with valid
    GT in at least ``min_frames`` frames, the coefficient of variation across those frames
    (std / mean) is taken for the prediction and for the GT, over the same frames. Returns
    their means and ``variation_ratio`` = prediction's / GT's: ~1 for a network that follows
    the scene, ~0 for one that predicts the same depth whatever the image (a prior or a
    constant gives exactly 0).
    """
    h = min(f.shape[0] for f in frames)
    w = min(f.shape[1] for f in frames)
    pred_grid, gt_grid = [], []
    for f in frames:
        gt = np.where(f.valid, f.gt_depth, 0.0)
        pd_ = np.minimum(pred[f.name], cap)
        gt = np.where(gt > cap, 0.0, gt)
        if gt.shape != (h, w):
            gt = cv2.resize(gt, (w, h), interpolation=cv2.INTER_NEAREST)
            pd_ = cv2.resize(pd_, (w, h), interpolation=cv2.INTER_NEAREST)
        pred_grid.append(pd_)
        gt_grid.append(gt)
    gt_s, pred_s = np.stack(gt_grid).astype(np.float64), np.stack(pred_grid).astype(np.float64)
    valid = gt_s > 0
    count = valid.sum(0)
    use = count >= min_frames
    if not use.any():
        return {
            "pixels": 0,
            "pred_variation": float("nan"),
            "gt_variation": float("nan"),
            "variation_ratio": float("nan"),
        }

    def cv(x: np.ndarray) -> np.ndarray:
        n = np.maximum(count, 1)
        mean = np.where(valid, x, 0.0).sum(0) / n
        var = np.where(valid, (x - mean) ** 2, 0.0).sum(0) / n
        return (np.sqrt(var) / np.maximum(mean, 1e-9))[use]

    pred_cv, gt_cv = float(cv(pred_s).mean()), float(cv(gt_s).mean())
    return {
        "pixels": int(use.sum()),
        "pred_variation": pred_cv,
        "gt_variation": gt_cv,
        "variation_ratio": pred_cv / gt_cv if gt_cv > 0 else float("nan"),
    }


def _boxes_for(rois: pd.DataFrame, frames: list[Frame]):
    """Yield (row number, ROI record, its frame, slice of the box), checking each box fits."""
    by_name = {f.name: f for f in frames}
    for i, roi in enumerate(rois.to_dict("records")):
        frame = by_name.get(roi["image"])
        if frame is None:
            raise DataError(f"ROI {i}: image {roi['image']!r} is not an evaluation frame")
        h, w = frame.shape
        if roi["x1"] > w or roi["y1"] > h:
            raise DataError(
                f"ROI {i} ({roi['image']}): box {roi['x0']},{roi['y0']},{roi['x1']},{roi['y1']} "
                f"exceeds {w}x{h}"
            )
        yield i, roi, frame, (slice(roi["y0"], roi["y1"]), slice(roi["x0"], roi["x1"]))


def _summarise_by_class(rows: list[dict], keys: tuple[str, ...]) -> dict:
    out = {"overall": {**_mean(rows, keys), "count": len(rows)}, "by_class": {}}
    for cls in sorted({r["class"] for r in rows}):
        sel = [r for r in rows if r["class"] == cls]
        out["by_class"][cls] = {**_mean(sel, keys), "count": len(sel)}
    return out


def _exact_row(pred: dict[str, np.ndarray], found: tuple, cap: float, cfg: EvalConfig) -> dict | None:
    """The metrics of one ROI (``found``: :func:`_boxes_for`'s item) on its box's exact pixels of its
    class, as a row of :func:`exact_mask_table`; None where they hold no valid GT."""
    i, roi, frame, box = found
    exact = (frame.class_map[box] & kitti.CLASS_BITS.get(roi["class"], 0)) > 0
    m = _metrics_in(frame, pred[frame.name][box], frame.valid[box] & exact, cap, cfg, box)
    return None if m is None else {"roi": i, "image": roi["image"], "class": roi["class"], "cap": cap, **m}


def exact_mask_table(
    pred: dict[str, np.ndarray], frames: list[Frame], rois: pd.DataFrame, cfg: EvalConfig
) -> pd.DataFrame:
    """Per ROI and cap, the metrics on the box's exact pixels of its class (every frame needs a class
    map): the units :func:`evaluate_roi`'s ``summary["masks"]`` averages; ROIs without valid GT there
    are left out."""
    rows = [
        row
        for cap in cfg.caps
        for found in _boxes_for(rois, frames)
        if (row := _exact_row(pred, found, cap, cfg)) is not None
    ]
    return pd.DataFrame(rows, columns=list(ROI_COLUMNS))


def exact_mask_summary(table: pd.DataFrame, n_rois: int, caps: Sequence[float]) -> dict | None:
    """:func:`evaluate_roi`'s ``summary["masks"]`` from :func:`exact_mask_table`'s rows of ``n_rois``
    ROIs: per cap, the means over the ROIs overall and by class; the ROIs scored (at the last cap
    that has any) and excluded. None without a row."""
    masks, kept = {}, 0
    for cap in caps:
        rows = table[table["cap"] == cap].to_dict("records")
        if rows:
            masks[f"cap{cap:g}"] = _summarise_by_class(rows, METRICS)
            kept = len(rows)
    return {**masks, "rois": kept, "excluded_rois": n_rois - kept} if masks else None


def evaluate_roi(
    pred: dict[str, np.ndarray],
    frames: list[Frame],
    rois: pd.DataFrame,
    cfg: EvalConfig,
    *,
    stereo: bool = False,
) -> tuple[dict, pd.DataFrame]:
    """Suite 2: the same metrics inside each ROI box; mean over ROIs, overall and per class.

    Where every frame has a class map (the synthetic set), ``summary["masks"]`` holds the same
    over each box's exact pixels of its class: a car box without the road and facade behind
    the car, a windshield box without the bonnet. ROIs whose exact pixels have no valid GT are
    excluded there and counted. No ROI at all gives ``{"rois": 0, NO_ROIS: why}`` and a
    header-only table. ``stereo``: each box's KITTI D1 and EPE too (an extra set's boxes, as its
    full-image suite has them).
    """
    keys = (*METRICS, *STEREO_METRICS) if stereo else METRICS
    if rois.empty:
        return _no_roi_result((*ROI_COLUMNS, *keys[len(METRICS) :]))
    rows, summary = [], {}
    masked = all(f.class_map is not None for f in frames)
    mask_rows: list[dict] = []
    for cap in cfg.caps:
        per_cap = []
        for i, roi, frame, box in _boxes_for(rois, frames):
            valid = frame.valid[box]
            m = _metrics_in(frame, pred[frame.name][box], valid, cap, cfg, box, stereo=stereo)
            if m is not None:
                per_cap.append({"roi": i, "image": roi["image"], "class": roi["class"], "cap": cap, **m})
            if masked and (m := _exact_row(pred, (i, roi, frame, box), cap, cfg)) is not None:
                mask_rows.append(m)
        if not per_cap:
            raise DataError("ROI evaluation: no ROI has valid ground truth")
        summary[f"cap{cap:g}"] = _summarise_by_class(per_cap, keys)
        rows += per_cap
    summary["rois"] = len(rois)
    summary["excluded_rois"] = len(rois) - len(rows) // len(cfg.caps)
    masks = exact_mask_summary(pd.DataFrame(mask_rows, columns=list(ROI_COLUMNS)), len(rois), cfg.caps)
    if masks is not None:
        summary["masks"] = masks
    return summary, pd.DataFrame(rows)


def gradient_maps(depth: np.ndarray) -> dict[str, np.ndarray]:
    """|Sobel x|, |Sobel y| (3x3) and |Laplacian| (3x3 aperture) of a depth map (float64)."""
    d = depth.astype(np.float64)
    return {
        "sobel_x": np.abs(cv2.Sobel(d, cv2.CV_64F, 1, 0, ksize=3)),
        "sobel_y": np.abs(cv2.Sobel(d, cv2.CV_64F, 0, 1, ksize=3)),
        "laplacian": np.abs(cv2.Laplacian(d, cv2.CV_64F, ksize=1)),
    }


def evaluate_gradients(
    pred: dict[str, np.ndarray], frames: list[Frame], rois: pd.DataFrame, cfg: EvalConfig
) -> tuple[dict, pd.DataFrame]:
    """Suite 3: mean absolute depth derivatives in each ROI (lower = smoother, more consistent).

    Derivatives are taken on the whole capped depth map and then cropped, so the box edge
    sees its real neighbours. Where the ROI's GT is dense (valid fraction >= dense_gt_fraction)
    the GT's derivatives are reported too, over pixels whose 3x3 neighbourhood is valid,
    together with the prediction's over the same pixels and the mean |pred - GT| derivative.
    No ROI at all gives ``{"rois": 0, NO_ROIS: why}`` and a header-only table.
    """
    if rois.empty:
        return _no_roi_result(GRADIENT_COLUMNS)
    kernel = np.ones((3, 3), np.uint8)
    rows, summary = [], {}
    for cap in cfg.caps:
        per_cap = []
        pred_grads = {f.name: gradient_maps(clamp_depth(pred[f.name], cfg.min_depth, cap)) for f in frames}
        gt_cache: dict[str, tuple[dict, np.ndarray]] = {}
        for i, roi, frame, box in _boxes_for(rois, frames):
            row = {"roi": i, "image": roi["image"], "class": roi["class"], "cap": cap}
            pred_grad = pred_grads[frame.name]
            row.update({f"pred_{g}": float(pred_grad[g][box].mean()) for g in GRADIENTS})
            valid = frame.valid[box]
            row["gt_valid_fraction"] = float(valid.mean())
            if row["gt_valid_fraction"] >= cfg.dense_gt_fraction:
                if frame.name not in gt_cache:
                    mask = frame.valid
                    gt_depth = np.where(mask, np.minimum(frame.gt_depth, cap), 0.0)
                    inner = (
                        cv2.erode(
                            mask.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0
                        )
                        > 0
                    )
                    gt_cache[frame.name] = (gradient_maps(gt_depth), inner)
                gt_grad, inner = gt_cache[frame.name]
                sel = inner[box]
                if sel.any():
                    for g in GRADIENTS:
                        row[f"gt_{g}"] = float(gt_grad[g][box][sel].mean())
                        row[f"pred_on_gt_{g}"] = float(pred_grad[g][box][sel].mean())
                        row[f"error_{g}"] = float(
                            np.abs(pred_grad[g][box][sel] - gt_grad[g][box][sel]).mean()
                        )
            per_cap.append(row)
        keys = tuple(f"pred_{g}" for g in GRADIENTS)
        block = _summarise_by_class(per_cap, keys)
        dense = [r for r in per_cap if "gt_sobel_x" in r]
        gt_keys = tuple(f"{p}_{g}" for p in ("gt", "pred_on_gt", "error") for g in GRADIENTS)
        block["dense_gt"] = (
            _summarise_by_class(dense, gt_keys) if dense else {"overall": {"count": 0}, "by_class": {}}
        )
        summary[f"cap{cap:g}"] = block
        rows += per_cap
    summary["rois"] = len(rois)
    return summary, pd.DataFrame(rows)


def read_depth_maps(path: str | os.PathLike, frames: Sequence[Frame] | None = None) -> dict[str, np.ndarray]:
    """Depth maps written by the depth stage (an ``.npz`` keyed by frame). Given the evaluation
    ``frames``, each must be there as a float map of its frame's GT size with depths > 0 (inf: no
    match); a file that is not (damaged, or written by other code) is a DataError naming it."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: no depth maps (run the depth stage)")
    maps = read_npz_file(path, "depth maps")
    for frame in frames or ():
        depth = maps.get(frame.name)
        if depth is None:
            raise DataError(
                f"{path}: no depth map of evaluation frame {frame.name!r}; re-run the depth stage"
            )
        if depth.shape != frame.shape or depth.dtype.kind != "f":
            raise DataError(
                f"{path}: frame {frame.name!r}'s depth map is {depth.dtype} {depth.shape}, expected a float "
                f"map of its GT's size {frame.shape}; re-run the depth stage"
            )
        if not (depth > 0).all():  # NaN compares False too
            raise DataError(
                f"{path}: frame {frame.name!r}'s depth map holds NaN or a depth <= 0; re-run the depth stage"
            )
    return maps
