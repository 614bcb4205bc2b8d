"""Stage ``baselines``: the image-blind baselines (constant, per-pixel prior) through every suite."""

from __future__ import annotations

import sys

from msdepth.config.params import Params
from msdepth.evaluation.baselines import score_baselines
from msdepth.pipeline.paths import EVAL_FRAMES, ROIS, TRAIN_PAIRS, run_stage


def baselines(params: Params) -> None:
    """The image-blind baselines, through the same depth conversion and suites as the variants.

    Their training GT is ``disp_02`` (synthetic) or the Velodyne scans (real KITTI); drives with
    neither are named and left out. With no GT at all the baselines are skipped, not failed: each
    leaves a ``{"skipped": reason}`` JSON (and a one-row CSV) that ``compare`` reports as missing.
    A stereo folder (data.source: folder) has no training GT: its baselines are always skipped.
    """
    score_baselines(params, TRAIN_PAIRS, EVAL_FRAMES, ROIS)


if __name__ == "__main__":
    sys.exit(run_stage(baselines, *sys.argv[1:]))
