"""Stage ``baselines``: the image-blind baselines (constant, per-pixel prior) through every suite."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

from msdepth.config.params import Params
from msdepth.data import kitti
from msdepth.data.index import read_eval_index
from msdepth.evaluation import baselines as baselines_mod
from msdepth.evaluation.results import run_suite
from msdepth.evaluation.suites import depth_maps, load_frames
from msdepth.pipeline.paths import EVAL_FRAMES, ROIS, SUITE_NAMES, run_stage

log = logging.getLogger("msdepth")

BASELINES = baselines_mod.BASELINES
FOLDER_REASON = "data.source folder: the training frames have no GT to build the baselines from"


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
        gt = baselines_mod.indexed_training_gt()
        reason = baselines_mod.skip_reason(gt) if gt.maps is None else None
    if reason is not None:
        for run in BASELINES:
            for suite in SUITE_NAMES:
                baselines_mod.write_skipped(
                    Path("metrics"), suite, run, reason, headline=suite in ("full", "roi")
                )
        return
    frames = load_frames(read_eval_index(EVAL_FRAMES))
    boxes = kitti.read_rois(ROIS)
    for run, disp in baselines_mod.baseline_disparities(gt.maps, len(frames)).items():
        pred = depth_maps(disp, frames)
        for suite in SUITE_NAMES:
            run_suite(params, suite, run, pred, frames, boxes)


if __name__ == "__main__":
    sys.exit(run_stage(baselines, *sys.argv[1:]))
