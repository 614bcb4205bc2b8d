"""The field's standard depth metrics, exactly as Monodepth's ``compute_errors``."""

from __future__ import annotations

import numpy as np

METRICS = ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")
# Lower is better for the errors, higher for the threshold accuracies.
HIGHER_IS_BETTER = {"a1", "a2", "a3"}


def compute_errors(gt: np.ndarray, pred: np.ndarray) -> dict[str, float]:
    """The 7 metrics of Monodepth's ``compute_errors`` on 1-D arrays of valid depths (metres).

    Same formulas and order of operations as mrharicot/monodepth ``utils/evaluation_utils.py``:
    a_k = mean(max(gt/pred, pred/gt) < 1.25**k); rmse and rmse_log as root of mean squares;
    abs_rel = mean(|gt - pred| / gt); sq_rel = mean((gt - pred)**2 / gt).
    """
    gt, pred = np.asarray(gt), np.asarray(pred)
    if gt.shape != pred.shape or gt.ndim != 1:
        raise ValueError(
            f"compute_errors expects two 1-D arrays of equal length, got {gt.shape} and {pred.shape}"
        )
    if gt.size == 0:
        raise ValueError("compute_errors got no valid pixels")
    thresh = np.maximum((gt / pred), (pred / gt))
    a1 = (thresh < 1.25).mean()
    a2 = (thresh < 1.25**2).mean()
    a3 = (thresh < 1.25**3).mean()

    rmse = (gt - pred) ** 2
    rmse = np.sqrt(rmse.mean())

    rmse_log = (np.log(gt) - np.log(pred)) ** 2
    rmse_log = np.sqrt(rmse_log.mean())

    abs_rel = np.mean(np.abs(gt - pred) / gt)
    sq_rel = np.mean(((gt - pred) ** 2) / gt)
    values = (abs_rel, sq_rel, rmse, rmse_log, a1, a2, a3)
    return {name: float(v) for name, v in zip(METRICS, values)}
