"""The field's standard depth metrics, exactly as Monodepth's ``compute_errors``, KITTI's stereo
metrics on disparity (D1, end-point error), and the Eigen split's evaluation crop and median
scaling, as Monodepth2's ``evaluate_depth.py`` applies them."""

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

    Args:
        gt: ground-truth depths (m), every one > 0.
        pred: predicted depths (m) at the same pixels, every one > 0 (clamped by the caller).

    Returns:
        ``abs_rel``, ``sq_rel``, ``rmse``, ``rmse_log``, ``a1``, ``a2``, ``a3`` (:data:`METRICS`).

    Raises:
        ValueError: arrays that are not 1-D, of different lengths or empty.

    Example:
        >>> import numpy as np
        >>> errors = compute_errors(np.array([10.0, 20.0]), np.array([11.0, 20.0]))
        >>> {name: round(value, 4) for name, value in errors.items()}
        {'abs_rel': 0.05, 'sq_rel': 0.05, 'rmse': 0.7071, 'rmse_log': 0.0674, 'a1': 1.0, 'a2': 1.0, 'a3': 1.0}
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
    return {name: float(v) for name, v in zip(METRICS, values, strict=True)}


# KITTI's stereo metrics of :func:`stereo_errors`, reported beside METRICS by the full-image suite
# (lower is better for both).
STEREO_METRICS = ("d1", "epe")
# KITTI's stereo outlier (devkit, D1): an error above 3 px and above 5 % of the true disparity.
D1_PIXELS = 3.0
D1_FRACTION = 0.05


def stereo_errors(gt_disp: np.ndarray, pred_disp: np.ndarray) -> dict[str, float]:
    """KITTI's stereo metrics of a disparity map (px) against GT of the same shape (px, 0 = none).

    ``d1``: the share (0..1) of GT pixels whose error ``|pred - gt|`` exceeds both 3 px and 5 % of
    the GT disparity (the KITTI 2015 devkit's outlier; the benchmark reports it in %); ``epe``: the
    mean absolute error (px) over the same pixels. The prediction must be dense there.

    Args:
        gt_disp: GT disparity (px); 0 where there is none.
        pred_disp: predicted disparity (px), the shape of ``gt_disp``.

    Returns:
        ``{"d1": share of outliers, "epe": mean absolute error in px}`` over the GT pixels.

    Raises:
        ValueError: maps of different shapes, no GT pixel, or a prediction not finite at one.

    Example:
        >>> import numpy as np
        >>> gt = np.array([[10.0, 100.0, 0.0]])  # the last pixel has no GT
        >>> stereo_errors(gt, np.array([[14.0, 104.0, 50.0]]))  # 4 px off: 40 % of 10 px, 4 % of 100
        {'d1': 0.5, 'epe': 4.0}
    """
    gt, pred = np.asarray(gt_disp, dtype=np.float64), np.asarray(pred_disp, dtype=np.float64)
    if gt.shape != pred.shape:
        raise ValueError(f"stereo_errors expects maps of one shape, got {gt.shape} and {pred.shape}")
    valid = gt > 0
    if not valid.any():
        raise ValueError("stereo_errors got no GT pixels")
    if not np.isfinite(pred[valid]).all():
        raise ValueError("stereo_errors: the prediction is not finite at every GT pixel")
    error = np.abs(pred[valid] - gt[valid])
    outliers = (error > D1_PIXELS) & (error > D1_FRACTION * gt[valid])
    return dict(zip(STEREO_METRICS, (float(outliers.mean()), float(error.mean())), strict=True))


# Garg et al.'s crop of the Eigen split, as fractions of the GT image size (Monodepth2's
# evaluate_depth.py; Monodepth's evaluate_kitti.py uses the same numbers).
GARG_CROP = (0.40810811, 0.99189189, 0.03594771, 0.96405229)  # top, bottom, left, right


def garg_crop_mask(height: int, width: int) -> np.ndarray:
    """Bool ``(height, width)`` mask of the Garg crop: rows [0.408 h, 0.992 h), cols [0.036 w, 0.964 w).

    The bounds are truncated to integers as the anchors do (``.astype(np.int32)``), so that the
    evaluated pixels are exactly theirs.
    """
    if height <= 0 or width <= 0:
        raise ValueError(f"garg_crop_mask: the size must be positive, got {height}x{width}")
    top, bottom, left, right = (
        np.array([GARG_CROP[0] * height, GARG_CROP[1] * height, GARG_CROP[2] * width, GARG_CROP[3] * width])
        .astype(np.int32)
        .tolist()
    )
    mask = np.zeros((height, width), dtype=bool)
    mask[top:bottom, left:right] = True
    return mask


def median_scale(gt: np.ndarray, pred: np.ndarray) -> tuple[np.ndarray, float]:
    """``pred`` times median(gt) / median(pred) over the same valid pixels, and that ratio.

    Monodepth2's per-image scaling of a monocular model's up-to-scale depth (applied before the
    prediction is clamped); a metric (stereo-trained) model's ratios sit near 1.
    """
    gt, pred = np.asarray(gt), np.asarray(pred)
    if gt.shape != pred.shape or gt.ndim != 1 or gt.size == 0:
        raise ValueError(
            f"median_scale expects two non-empty 1-D arrays of equal length, got {gt.shape}, {pred.shape}"
        )
    ratio = float(np.median(gt) / np.median(pred))
    return pred * ratio, ratio
