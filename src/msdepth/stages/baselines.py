"""Stage ``baselines``: the image-blind baselines (constant, per-pixel prior) through every suite."""

from __future__ import annotations

import logging
from pathlib import Path

from .. import baselines as baselines_mod
from ..config import Params
from ..data import kitti
from ..data.index import read_eval_index
from ..data.pairs import load_pair_list
from ..evaluate import depth_maps, load_frames
from ..io import write_json, write_text
from .common import INDEX_DIR, SUITE_NAMES
from .evaluate import run_suite

log = logging.getLogger("msdepth")

BASELINES = baselines_mod.BASELINES
FOLDER_REASON = "data.source folder: the training frames have no GT to build the baselines from"


def training_gt() -> baselines_mod.TrainingGT:
    """The training frames' GT the baselines are built from, with a warning per drive without."""
    pairs = load_pair_list(INDEX_DIR / "train_pairs.txt")
    gt = baselines_mod.training_gt([left for left, _ in pairs])
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


def skip_reason(gt: baselines_mod.TrainingGT) -> str:
    reason = f"no training frame has GT (disp_02 or a Velodyne scan) in {len(gt.missing)} drive(s)"
    log.warning("baselines: %s: %s not built", reason, " and ".join(BASELINES))
    return reason


def baselines(params: Params) -> None:
    """The image-blind baselines, through the same depth conversion and suites as the variants.

    Their training GT is ``disp_02`` (synthetic) or the Velodyne scans (real KITTI); drives with
    neither are named and left out. With no GT at all the baselines are skipped, not failed: each
    leaves a ``{"skipped": reason}`` JSON (and a one-row CSV) that ``compare`` reports as missing.
    A stereo folder (data.source: folder) has no training GT: its baselines are always skipped.
    """
    if params.data.source == "folder":
        reason = FOLDER_REASON
        log.warning("baselines: %s: %s not built", reason, " and ".join(BASELINES))
    else:
        gt = training_gt()
        reason = skip_reason(gt) if gt.maps is None else None
    if reason is not None:
        for run in BASELINES:
            for suite in SUITE_NAMES:
                write_skipped(Path("metrics"), suite, run, reason, headline=suite in ("full", "roi"))
        return
    frames = load_frames(read_eval_index(INDEX_DIR / "eval_frames.csv"))
    boxes = kitti.read_rois(INDEX_DIR / "rois.csv")
    for run, disp in baselines_mod.baseline_disparities(gt.maps, len(frames)).items():
        pred = depth_maps(disp, frames)
        for suite in SUITE_NAMES:
            run_suite(params, suite, run, pred, frames, boxes)


def write_skipped(
    root: Path, suite: str, run: str, reason: str, headline: bool, headline_root: str = ""
) -> None:
    """A skipped baseline's files: ``{"skipped": reason}`` where its metrics would be."""
    write_json(root / suite / f"{run}.json", {baselines_mod.SKIPPED: reason})
    write_text(root / suite / f"{run}.csv", f"{baselines_mod.SKIPPED}\n{reason}\n")
    if headline:  # the headline files are declared DVC metrics too
        write_json(
            Path("metrics") / "headline" / headline_root / suite / f"{run}.json",
            {baselines_mod.SKIPPED: reason},
        )
