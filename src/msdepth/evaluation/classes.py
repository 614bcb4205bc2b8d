"""Exact-mask scores of whole frames, per pixel class: the exact-mask suite for a set whose frames
carry class maps but no exact boxes (KITTI 2012's ``reflective`` class, :mod:`msdepth.data.kitti2012`;
KITTI 2015's ``car`` from ``obj_map``; a stereo folder's class maps, :mod:`msdepth.data.folder`),
which the full-image suite adds (:func:`msdepth.evaluation.results.exact_classes`).

Each frame gets one whole-frame ROI per class its class map holds, so the ROI suite's exact masks
(:func:`msdepth.evaluation.suites.evaluate_roi`, ``summary["masks"]``) score exactly that class's
GT pixels with the same caps and depth metrics as every suite; KITTI's stereo metrics D1 and EPE
(:func:`msdepth.evaluation.metrics.stereo_errors`) are added per class, on the disparity
``focal·baseline / depth`` of the uncapped prediction, averaged over the frames that have the class.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from msdepth.config.params import EvalConfig
from msdepth.data.kitti import CLASS_BITS, ROI_COLUMNS
from msdepth.evaluation.metrics import stereo_errors
from msdepth.evaluation.suites import Frame, evaluate_roi


def whole_frame_rois(frames: list[Frame]) -> pd.DataFrame:
    """One box over the whole frame per class whose bit a frame's class map has, as ROI rows."""
    rows = []
    for frame in frames:
        if frame.class_map is None:
            continue
        height, width = frame.shape
        rows += [
            (frame.name, cls, 0, 0, width, height)
            for cls, bit in CLASS_BITS.items()
            if (frame.class_map & bit).any()
        ]
    return pd.DataFrame(rows, columns=list(ROI_COLUMNS))


def stereo_by_class(pred: dict[str, np.ndarray], frames: list[Frame], cfg: EvalConfig) -> dict:
    """Per class: D1 (%) and EPE (px) on the class's GT pixels, mean over the frames that have some,
    and their count."""
    per_class: dict[str, list[dict[str, float]]] = {}
    for frame in frames:
        if frame.class_map is None:
            continue
        fb = frame.focal * frame.baseline
        gt_disp = np.where(frame.valid, fb / np.maximum(frame.gt_depth, cfg.min_depth), 0.0)
        pred_disp = fb / np.maximum(pred[frame.name], cfg.min_depth)
        for cls, bit in CLASS_BITS.items():
            mask = (frame.class_map & bit) > 0
            if (mask & frame.valid).any():
                found = stereo_errors(np.where(mask, gt_disp, 0.0), pred_disp)
                per_class.setdefault(cls, []).append(found)
    return {
        cls: {
            "d1": 100 * float(np.mean([r["d1"] for r in rows])),
            "epe": float(np.mean([r["epe"] for r in rows])),
            "frames": len(rows),
        }
        for cls, rows in sorted(per_class.items())
    }


def exact_class_summary(pred: dict[str, np.ndarray], frames: list[Frame], cfg: EvalConfig) -> dict | None:
    """The exact-mask summary of every class the frames' class maps hold (per cap, overall and by
    class, as the ROI suite's ``masks``), with ``stereo`` (:func:`stereo_by_class`); None when no
    frame has a class map or a class pixel."""
    if not frames or any(f.class_map is None for f in frames):
        return None
    rois = whole_frame_rois(frames)
    if rois.empty:
        return None
    masks = evaluate_roi(pred, frames, rois, cfg)[0].get("masks")
    if masks is None:
        return None
    return {**masks, "stereo": stereo_by_class(pred, frames, cfg)}
