"""Exact-mask scores of whole frames, per pixel class: the exact-mask suite for a set whose frames
carry class maps but no exact boxes (KITTI 2012's ``reflective`` class, :mod:`msdepth.data.kitti2012`;
KITTI 2015's ``car`` from ``obj_map``; a stereo folder's class maps, :mod:`msdepth.data.folder`),
which the full-image suite adds (:func:`msdepth.evaluation.results.full_suite`).

Each frame gets one whole-frame ROI per class its class map holds, so the ROI suite's exact masks
(:func:`msdepth.evaluation.suites.exact_mask_table`, summarised as its ``summary["masks"]``) score
exactly that class's GT pixels with the same caps and depth metrics as every suite; KITTI's stereo
metrics D1 and EPE (:func:`msdepth.evaluation.metrics.stereo_errors`) are added per class, on the disparity
``focal·baseline / depth`` of the uncapped prediction, averaged over the frames that have the class.

The per-image table of the full-image suite gets each class's abs_rel per frame as a column
``<class>_abs_rel`` (:func:`with_class_columns`; empty where a frame lacks the class), so that
the comparison pairs two runs frame by frame on a class as on the whole frame
(:func:`class_unit_tables`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from msdepth.config.params import EvalConfig
from msdepth.data.kitti import CLASS_BITS, ROI_COLUMNS
from msdepth.evaluation.metrics import stereo_errors
from msdepth.evaluation.suites import Frame, exact_mask_summary, exact_mask_table

CLASS_COLUMN = "{}_abs_rel"  # a class's per-frame abs_rel in the full-image suite's table


def _whole_frame_rois(frames: list[Frame]) -> pd.DataFrame:
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


def _stereo_by_class(pred: dict[str, np.ndarray], frames: list[Frame], cfg: EvalConfig) -> dict:
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


def exact_class_scores(
    pred: dict[str, np.ndarray], frames: list[Frame], cfg: EvalConfig
) -> tuple[dict, pd.DataFrame] | None:
    """The exact-mask scores of every class the frames' class maps hold: the summary (per cap,
    overall and by class, as the ROI suite's ``masks``, with ``stereo``: :func:`_stereo_by_class`)
    and the per-frame rows it averages (:func:`~msdepth.evaluation.suites.exact_mask_table` of one
    whole-frame ROI per frame and class). None when a frame has no class map or none a class pixel."""
    if not frames or any(f.class_map is None for f in frames):
        return None
    rois = _whole_frame_rois(frames)
    if rois.empty:
        return None
    exact = exact_mask_table(pred, frames, rois, cfg)
    masks = exact_mask_summary(exact, len(rois), cfg.caps)
    if masks is None:
        return None
    return {**masks, "stereo": _stereo_by_class(pred, frames, cfg)}, exact


def with_class_columns(table: pd.DataFrame, exact: pd.DataFrame) -> pd.DataFrame:
    """The full-image suite's per-image ``table`` (``frame``, ``cap``, metrics) with each class's
    abs_rel on the frame's exact pixels of it (``exact``: :func:`exact_class_scores`' rows) as a
    column :data:`CLASS_COLUMN` (NaN where the frame has no valid GT of the class): the units of
    the summary's means.

    >>> car = np.array([[CLASS_BITS["car"], 0], [0, 0]], np.uint8)
    >>> frame = Frame("f", np.full((2, 2), 10.0), 1.0, 1.0, class_map=car, whole_frame_classes=True)
    >>> _, exact = exact_class_scores({"f": np.full((2, 2), 12.0)}, [frame], EvalConfig(caps=(80.0,)))
    >>> table = pd.DataFrame({"frame": ["f"], "cap": [80.0], "abs_rel": [0.0]})
    >>> with_class_columns(table, exact)["car_abs_rel"].round(3).tolist()
    [0.2]
    """
    if exact.empty:
        return table
    wide = exact.pivot_table(index=["image", "cap"], columns="class", values="abs_rel", aggfunc="first")
    wide.columns = [CLASS_COLUMN.format(c) for c in wide.columns]
    wide = wide.reset_index().rename(columns={"image": "frame"})
    return table.merge(wide, on=["frame", "cap"], how="left", validate="one_to_one")


def class_unit_tables(
    tables: dict[str, pd.DataFrame], anchor: str
) -> list[tuple[str, dict[str, pd.DataFrame]]]:
    """``(class, {run: table})`` per class column of ``anchor``'s full-image table (:data:`CLASS_COLUMN`):
    each run's frames that have the class, with that class's abs_rel as ``abs_rel``; [] without."""
    suffix = CLASS_COLUMN.format("")
    classes = sorted(c[: -len(suffix)] for c in tables[anchor].columns if c.endswith(suffix))
    out = []
    for cls in classes:
        column = CLASS_COLUMN.format(cls)
        out.append((cls, {run: t[t[column].notna()].assign(abs_rel=t[column]) for run, t in tables.items()}))
    return out
