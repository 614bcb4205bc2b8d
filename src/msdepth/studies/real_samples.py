"""The real KITTI sample frames the studies score (``../shared/real-samples``): their camera, the
scores of one method's disparity on one frame, the variants the studies compare and the LiDAR GT
of the raw pair.

The cap and minimum depth are the evaluation's own (:class:`msdepth.config.params.EvalConfig`'s
first cap and ``min_depth``), so a study scores as the pipeline does.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msdepth.config.params import (
    EvalConfig,
    Params,
    apply_overrides,
    load_params,
    params_from_dict,
    read_params_file,
)
from msdepth.data.kitti import lidar_depth_map, read_calib, read_velodyne
from msdepth.evaluation.metrics import compute_errors, stereo_errors
from msdepth.geometry.depth import clamp_depth, disparity_to_depth

# KITTI's colour camera P2 focal (px, at 1242 px wide) and the rig's baseline (m): the samples'
# calibration, shared by the 2012 and 2015 training frames.
FOCAL, BASELINE = 721.5377, 0.54
CAP, MIN_DEPTH = EvalConfig().caps[0], EvalConfig().min_depth
# (label, variant, overrides): the variants the optimum studies compare on the samples.
VARIANTS = (
    ("ssim", "ssim", []),
    ("msssim k3", "msssim", ["msssim.kernel_size=3"]),
    ("msssim k7", "msssim", ["msssim.kernel_size=7"]),
)


def samples_dir(repo: Path) -> Path:
    """Where the repository at ``repo`` finds the shared sample frames."""
    return repo.parent / "shared" / "real-samples"


@dataclass
class Result:
    """One method's disparity on one frame: the map (px), its pre-filling validity, seconds."""

    method: str
    disparity: np.ndarray
    valid: np.ndarray
    seconds: float
    loss: float | None = None  # an optimum's: the objective at its working size


def scores(gt_disp: np.ndarray, result: Result) -> dict[str, float]:
    """abs_rel (depth, capped), D1 (%), EPE (px) and the valid share (%) on the GT pixels."""
    mask = gt_disp > 0
    floor = FOCAL * BASELINE / CAP  # px: a disparity below it is beyond the cap
    pred = clamp_depth(
        disparity_to_depth(np.maximum(result.disparity, floor), FOCAL, BASELINE), MIN_DEPTH, CAP
    )
    gt = disparity_to_depth(gt_disp, FOCAL, BASELINE)
    stereo = stereo_errors(gt_disp, result.disparity)
    return {
        "abs_rel": compute_errors(gt[mask], pred[mask])["abs_rel"],
        "d1": 100 * stereo["d1"],
        "epe": stereo["epe"],
        "valid": 100 * float(result.valid[mask].mean()),
        "loss": result.loss,
    }


def variants_of(params_path: Path, assignments: list[str] = ()) -> dict[str, tuple[str, Params]]:
    """Each of :data:`VARIANTS`' ``(name, params)`` by label, from ``params_path`` with the
    ``--set`` ``assignments`` and the variant's overrides."""
    raw = read_params_file(params_path)
    out = {}
    for label, name, overrides in VARIANTS:
        params = (
            params_from_dict(apply_overrides(copy.deepcopy(raw), [*assignments, *overrides]))
            if overrides or assignments
            else load_params(params_path)
        )
        out[label] = (name, params)
    return out


def working_size(text: str | None, shape: tuple[int, ...]) -> tuple[int, int] | None:
    """``--refine``'s size for a frame of ``shape``: ``full``/``half``/``quarter`` of it, or ``HxW``."""
    if text is None:
        return None
    named = {"full": 1, "half": 2, "quarter": 4}
    if text in named:
        return shape[0] // named[text], shape[1] // named[text]
    height, _, width = text.partition("x")
    return int(height), int(width)


def lidar_gt(scan: Path, calib: Path, shape: tuple[int, int]) -> np.ndarray:
    """The scan's depth (m, 0 = none) in the left colour camera (``P2``) at ``shape``."""
    c = read_calib(calib)
    return lidar_depth_map(
        read_velodyne(scan),
        c["Tr_velo_to_cam"].reshape(3, 4),
        c["R0_rect"].reshape(3, 3),
        c["P2"].reshape(3, 4),
        shape,
    )
