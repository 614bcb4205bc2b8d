"""Image-blind baselines a trained network must beat: a constant and a per-pixel prior.

Both are built from the training frames' GT disparity only and never look at a test image,
so a variant that does not beat them has learned the average scene, not depth from the image.

Where the GT comes from: the synthetic set writes a dense ``disp_02`` map per training frame,
which is used as it is. A real KITTI raw drive has none; its GT is the frame's Velodyne scan
projected into camera 2 (:func:`msdepth.data.kitti.velodyne_depth`, the field's raw-LiDAR GT)
and turned into disparity with the focal and baseline the evaluation uses for that image width
(:func:`msdepth.data.kitti.focal_and_baseline`), so that the conversion back to depth is its
exact inverse (a width outside Monodepth's table takes them from the day's ``P_rect_02`` /
``P_rect_03``). KITTI's days differ in image size (1242 x 375, 1241 x 376, 1238 x 374,
1224 x 370, ...): maps of other sizes are resampled to the most common one, each valid sample
to the nearest pixel of that grid (the nearest point wins where two meet), as disparities are
fractions of the width and need no rescaling.
"""

from __future__ import annotations

import logging
import warnings
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
from tqdm import tqdm

from msdepth.config.params import Params
from msdepth.data import kitti
from msdepth.data.eval_index import read_eval_index, training_gt_path, velodyne_path
from msdepth.data.pairs import load_pair_list
from msdepth.evaluation.results import run_suite, score_set
from msdepth.evaluation.suites import depth_maps, load_frames
from msdepth.io import write_json, write_text
from msdepth.pipeline.paths import (
    HEADLINE,
    METRICS,
    SUITE_NAMES,
    headline_path,
    set_headline_dir,
    set_metrics_dir,
    suite_path,
)
from msdepth.readers import read_json_file

log = logging.getLogger("msdepth")

BASELINES = ("constant", "prior")
# The per-pixel median needs every frame's map in memory at once: above this many bytes of GT
# (about 1,150 KITTI frames at 1242 x 375, or 10,000 of the default synthetic frames) an evenly
# spaced subset of the training frames is used.
GT_MEMORY_BUDGET = 2 * 2**30
SKIPPED = "skipped"  # key of the metrics JSON a baseline that could not be built leaves behind
FOLDER_REASON = "data.source folder: the training frames have no GT to build the baselines from"


@dataclass
class TrainingGT:
    """Training GT disparities and where they came from.

    ``maps``: (N, H, W) float32, fraction of width, NaN where invalid; None if no frame has GT.
    ``sources``: frames read per source (``disp_02``, ``velodyne``). ``missing``: per drive
    folder, its frames with neither. ``available``: frames that had GT (``len(maps)`` is
    fewer when the memory budget took a subset). ``resampled``: maps brought to the common size.
    """

    maps: np.ndarray | None
    sources: dict[str, int] = field(default_factory=dict)
    missing: dict[str, int] = field(default_factory=dict)
    available: int = 0
    resampled: int = 0


def _gt_source(left_image: Path) -> tuple[str, Path] | None:
    """``("disp_02", png)``, else ``("velodyne", bin)``, for a training frame; None if it has neither."""
    disp = training_gt_path(left_image)
    if disp.is_file():
        return "disp_02", disp
    scan = velodyne_path(left_image)
    if scan.is_file():
        return "velodyne", scan
    return None


class _GTReader:
    """Reads training GT as disparity (fraction of width, NaN = none); one calibration read per day."""

    def __init__(self) -> None:
        self._days: dict[Path, tuple[kitti.RawCalib, float, float]] = {}

    def _day(self, scan: Path) -> tuple[kitti.RawCalib, float, float]:
        day = scan.parents[3]  # raw/<date>/<drive>_sync/velodyne_points/data/X.bin
        if day not in self._days:
            calib = kitti.read_raw_calib(day)
            focal, baseline = kitti.focal_and_baseline(calib.shape[1], day / "calib_cam_to_cam.txt")
            self._days[day] = calib, focal, baseline
        return self._days[day]

    def shape(self, kind: str, path: Path) -> tuple[int, int]:
        if kind == "velodyne":
            return self._day(path)[0].shape
        return kitti.read_disparity(path).shape

    def read(self, kind: str, path: Path) -> np.ndarray:
        if kind == "velodyne":
            calib, focal, baseline = self._day(path)
            depth = kitti.velodyne_depth(path, calib)
            frac = np.full(depth.shape, np.nan, dtype=np.float32)
            valid = depth > 0
            frac[valid] = focal * baseline / depth[valid] / depth.shape[1]
            return frac
        disp = kitti.read_disparity(path)
        frac = disp / disp.shape[1]
        frac[disp <= 0] = np.nan
        return frac


def _resample_sparse(frac: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A disparity map (fraction of width, NaN = none) on another grid: every valid sample moves to
    the pixel whose area holds its centre; where several meet the largest (nearest) wins.

    Unlike an image resize, no sample is lost or blended with the invalid pixels around it, which
    matters for sparse LiDAR maps; pixels that receive no sample are NaN.
    """
    h, w = frac.shape
    th, tw = shape
    rows, cols = np.nonzero(~np.isnan(frac))
    values = frac[rows, cols].astype(np.float64)
    target_rows = np.minimum(((rows + 0.5) * th / h).astype(np.int64), th - 1)
    target_cols = np.minimum(((cols + 0.5) * tw / w).astype(np.int64), tw - 1)
    flat = np.full(th * tw, -np.inf)
    np.maximum.at(flat, target_rows * tw + target_cols, values)
    flat[np.isneginf(flat)] = np.nan
    return flat.reshape(th, tw).astype(np.float32)


def training_gt(
    left_images: Sequence[Path], progress: bool = True, memory_budget: int = GT_MEMORY_BUDGET
) -> TrainingGT:
    """Every training frame's GT disparity (``disp_02``, else its Velodyne scan) at one common size.

    Frames with neither are left out and counted per drive. If the maps would exceed
    ``memory_budget`` bytes, an evenly spaced subset of the frames is read.
    """
    found: list[tuple[str, Path]] = []
    missing: Counter[str] = Counter()
    for left in map(Path, left_images):
        source = _gt_source(left)
        if source is None:
            missing[str(left.parent.parent.parent)] += 1
        else:
            found.append(source)
    if not found:
        return TrainingGT(None, missing=dict(missing))
    reader = _GTReader()
    shapes = [reader.shape(kind, path) for kind, path in found]
    limit = max(1, memory_budget // (4 * max(h * w for h, w in shapes)))
    chosen = range(len(found))
    if len(found) > limit:
        chosen = np.unique(np.linspace(0, len(found) - 1, limit).round().astype(int)).tolist()
    target = Counter(shapes[i] for i in chosen).most_common(1)[0][0]
    maps = np.empty((len(chosen), *target), dtype=np.float32)
    sources: Counter[str] = Counter()
    resampled = 0
    for slot, i in enumerate(tqdm(chosen, desc="training GT", disable=not progress, leave=False)):
        kind, path = found[i]
        frac = reader.read(kind, path)
        if frac.shape != target:
            frac = _resample_sparse(frac, target)
            resampled += 1
        maps[slot] = frac
        sources[kind] += 1
    return TrainingGT(maps, dict(sources), dict(missing), len(found), resampled)


def _constant_prior(gt: np.ndarray) -> float:
    """Median valid training disparity (fraction of width)."""
    return float(np.nanmedian(gt))


def _per_pixel_prior(gt: np.ndarray, rows_per_band: int = 16) -> np.ndarray:
    """Per-pixel median of the valid training disparities; pixels never valid get the global median.

    Computed a band of rows at a time: the same medians, without a second copy of the whole stack.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN pixels (sky) are expected
        prior = np.concatenate(
            [np.nanmedian(gt[:, r : r + rows_per_band], axis=0) for r in range(0, gt.shape[1], rows_per_band)]
        )
    prior[np.isnan(prior)] = _constant_prior(gt)
    return prior.astype(np.float32)


def baseline_disparities(gt: np.ndarray, num_frames: int) -> dict[str, np.ndarray]:
    """Predictions of both baselines for ``num_frames`` frames, in the layout of inference output."""
    prior = _per_pixel_prior(gt)
    return {
        "constant": np.full((num_frames, *prior.shape), _constant_prior(gt), dtype=np.float32),
        "prior": np.broadcast_to(prior, (num_frames, *prior.shape)).copy(),
    }


def skipped_reason(metrics_dir: str | Path, run: str, suites: Sequence[str]) -> str | None:
    """Why baseline ``run`` has no metrics (its JSON says ``skipped``, or there is none); None if it has."""
    for suite in suites:
        path = suite_path(suite, run, ".json", Path(metrics_dir))
        if not path.is_file():
            return f"no {path}"
        data = read_json_file(path, "metrics")
        if isinstance(data, dict) and SKIPPED in data:
            return str(data[SKIPPED])
    return None


def _indexed_training_gt(train_pairs: Path) -> TrainingGT:
    """The GT of the indexed training frames (the pair list ``train_pairs``, the index stage's)
    that the stages build the baselines from, logged, with a warning per drive without."""
    pairs = load_pair_list(train_pairs)
    gt = training_gt([left for left, _ in pairs])
    for drive, count in gt.missing.items():
        log.warning(
            "baselines: %s: %d training frame(s) with neither disp_02/data/<frame>.png nor "
            "velodyne_points/data/<frame>.bin, left out",
            drive,
            count,
        )
    if gt.maps is not None:
        used, (h, w) = len(gt.maps), gt.maps.shape[1:]
        subset = f" (an evenly spaced {used} of {gt.available}: memory budget)" if used < gt.available else ""
        resampled = f", {gt.resampled} resampled from other sizes" if gt.resampled else ""
        log.info(
            "baselines: training GT of %d frames%s at %dx%d%s: %s", used, subset, h, w, resampled, gt.sources
        )
    return gt


def _skip_reason(gt: TrainingGT) -> str:
    """Why the baselines are not built when no training frame has GT (also logged)."""
    reason = f"no training frame has GT (disp_02 or a Velodyne scan) in {len(gt.missing)} drive(s)"
    log.warning("baselines: %s: %s not built", reason, " and ".join(BASELINES))
    return reason


def write_skipped(
    root: Path, suite: str, run: str, reason: str, headline: bool, headline_root: Path = HEADLINE
) -> None:
    """A skipped baseline's files: ``{"skipped": reason}`` where its metrics would be."""
    write_json(suite_path(suite, run, ".json", root), {SKIPPED: reason})
    write_text(suite_path(suite, run, ".csv", root), f"{SKIPPED}\n{reason}\n")
    if headline:  # the headline files are declared DVC metrics too
        write_json(headline_path(suite, run, headline_root), {SKIPPED: reason})


def score_baselines(params: Params, train_pairs: Path, eval_index: Path, rois: Path) -> None:
    """Both baselines, built from the GT of the training frames of ``train_pairs``, through the same
    depth conversion and every suite as a trained run, on the frames of ``eval_index`` (ROIs
    ``rois``).

    Drives without GT are named and left out. With no GT at all the baselines are skipped, not
    failed: each leaves a ``{"skipped": reason}`` JSON (and a one-row CSV) that the comparison
    reports as missing. A stereo folder (data.source: folder) has no training GT: its baselines
    are always skipped.
    """
    if params.data.source == "folder":
        reason = FOLDER_REASON
        log.warning("baselines: %s: %s not built", reason, " and ".join(BASELINES))
    else:
        gt = _indexed_training_gt(train_pairs)
        reason = _skip_reason(gt) if gt.maps is None else None
    if reason is not None:
        for run in BASELINES:
            for suite in SUITE_NAMES:
                write_skipped(METRICS, suite, run, reason, headline=suite in ("full", "roi"))
        return
    frames = load_frames(read_eval_index(eval_index))
    boxes = kitti.read_rois(rois)
    for run, disp in baseline_disparities(gt.maps, len(frames)).items():
        pred = depth_maps(disp, frames)
        for suite in SUITE_NAMES:
            run_suite(params, suite, run, pred, frames, boxes)


def score_set_baselines(
    params: Params, name: str, train_pairs: Path, set_index: Path, rois: Path | None = None
) -> None:
    """Both baselines of the GT of the training frames of ``train_pairs`` scored on extra set
    ``name``'s full images (its index ``set_index``) and, with ``rois``, its boxes; skipped, with
    the reason in their JSON, when no training frame has GT."""
    gt = _indexed_training_gt(train_pairs)
    if gt.maps is None:
        for run in BASELINES:
            write_set_skipped(name, run, _skip_reason(gt), rois is not None)
        return
    frames = load_frames(read_eval_index(set_index))
    for run, disp in baseline_disparities(gt.maps, len(frames)).items():
        score_set(params, name, run, depth_maps(disp, frames), frames, rois=rois)


def write_set_skipped(name: str, run: str, reason: str, rois: bool) -> None:
    """A skipped run's files on extra set ``name`` (:func:`write_skipped`): its full-image suite's
    and, with ``rois``, its ROI suite's."""
    for suite in ("full", "roi") if rois else ("full",):
        write_skipped(set_metrics_dir(name), suite, run, reason, True, set_headline_dir(name))
