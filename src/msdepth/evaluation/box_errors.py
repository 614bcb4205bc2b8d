"""Per-box errors against the image-blind prior: does a network place an object from the image?

For every ROI box the median predicted depth and the median GT over the box's valid GT pixels
(cap ``cap``) give a log ratio log(prediction / GT). Over boxes, the correlation of a run's log
ratios with the per-pixel prior's says where its errors come from: near 1 (with alike ratios) the
network puts the object where the layout prior puts it, from its image position, not from the
stereo cue; near 0 its errors are its own.
"""

from __future__ import annotations

import numpy as np
import pandas as pd


def box_medians(
    depth: dict[str, np.ndarray],
    frames: dict,
    boxes: pd.DataFrame,
    cap: float = 80.0,
    min_depth: float = 1e-3,
) -> np.ndarray:
    """Per box, ``[median depth, median GT]`` over its GT pixels in (0, cap]; NaN where it has none.

    Args:
        depth: depth maps (m) by frame name, at the GT's size.
        frames: :class:`msdepth.evaluation.suites.Frame` by name.
        boxes: the ROI table (``image``, ``x0``, ``y0``, ``x1``, ``y1``).
        cap: the largest GT depth used, and the clamp of the prediction (Monodepth's).
        min_depth: the prediction's lower clamp.

    Returns:
        An array of shape ``(len(boxes), 2)``.

    Example:
        >>> import pandas as pd
        >>> from types import SimpleNamespace
        >>> gt = np.full((4, 4), 10.0)
        >>> frames = {"a": SimpleNamespace(gt_depth=gt)}
        >>> boxes = pd.DataFrame({"image": ["a"], "x0": [0], "y0": [0], "x1": [2], "y1": [2]})
        >>> box_medians({"a": np.full((4, 4), 20.0)}, frames, boxes).tolist()
        [[20.0, 10.0]]
    """
    out = np.full((len(boxes), 2), np.nan)
    for i, box in enumerate(boxes.itertuples()):
        gt = frames[box.image].gt_depth[box.y0 : box.y1, box.x0 : box.x1]
        pred = np.clip(depth[box.image][box.y0 : box.y1, box.x0 : box.x1], min_depth, cap)
        valid = (gt > 0) & (gt <= cap)
        if valid.any():
            out[i] = float(np.median(pred[valid])), float(np.median(gt[valid]))
    return out


def prior_correlation(run: np.ndarray, prior: np.ndarray, select: np.ndarray | None = None) -> dict:
    """Over the selected boxes with medians in both, the correlation of log(run / GT) with
    log(prior / GT), and each one's median ratio; ``n`` boxes (NaN correlation below 3).

    Example:
        >>> run = np.array([[12.0, 10.0], [30.0, 20.0], [8.0, 10.0]])
        >>> prior = np.array([[13.0, 10.0], [32.0, 20.0], [7.0, 10.0]])
        >>> r = prior_correlation(run, prior)
        >>> r["n"], round(r["corr"], 3) > 0.9
        (3, True)
    """
    keep = np.isfinite(run).all(axis=1) & np.isfinite(prior).all(axis=1)
    if select is not None:
        keep &= select
    ours = np.log(run[keep, 0] / run[keep, 1])
    theirs = np.log(prior[keep, 0] / prior[keep, 1])
    n = int(keep.sum())
    corr = (
        float(np.corrcoef(ours, theirs)[0, 1])
        if n >= 3 and ours.std() > 0 and theirs.std() > 0
        else float("nan")
    )
    return {
        "n": n,
        "corr": corr,
        "run_ratio": float(np.exp(np.median(ours))) if n else float("nan"),
        "prior_ratio": float(np.exp(np.median(theirs))) if n else float("nan"),
    }
