"""The synthetic set's evaluation frames rendered in memory, for studies that compare cameras or
solvers on the same scenes without writing the set (studies/optimum_sweep.py, studies/camera_screen.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from msdepth.config.params import CameraConfig, SyntheticConfig
from msdepth.data.kitti import KITTI_BASELINE
from msdepth.evaluation.suites import Frame
from msdepth.render import render_frame, within_range

EVAL_SPLIT = 1  # render_frame's split of the evaluation frames
ROI_KEYS = ("image", "class", "x0", "y0", "x1", "y1")


@dataclass(frozen=True)
class RenderedSet:
    """Evaluation frames' ``(left, right)`` uint8 RGB pairs, their GT frames (with class maps) and ROI
    boxes (the columns of :data:`ROI_KEYS`)."""

    pairs: list[tuple[np.ndarray, np.ndarray]]
    frames: list[Frame]
    rois: pd.DataFrame


def rendered_eval_set(cfg: SyntheticConfig, count: int, sensor: CameraConfig | None) -> RenderedSet:
    """Evaluation frames 0..count-1 of ``cfg``'s set, recorded by ``sensor`` (None or disabled: the
    ideal views), with exact GT: the rendered disparity (occluded pixels included) within
    ``cfg.gt_max_depth``."""
    pairs, frames, rois = [], [], []
    for i in range(count):
        f = render_frame(cfg.seed, EVAL_SPLIT, i, cfg.height, cfg.width, sensor=sensor)
        name = f"{i:06d}_10"
        gt = within_range(f.disp, f.focal, cfg.gt_max_depth)
        pairs.append((f.left, f.right))
        frames.append(Frame.from_disparity(name, gt, f.focal, KITTI_BASELINE, class_map=f.class_map))
        rois += [dict(zip(ROI_KEYS, (name, *roi), strict=True)) for roi in f.rois]
    return RenderedSet(pairs, frames, pd.DataFrame(rois, columns=list(ROI_KEYS)))
