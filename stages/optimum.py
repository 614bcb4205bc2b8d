"""Stage ``optimum@<variant>-<weight>``: the variant's own optimum disparity of the evaluation
frames at one smoothness weight (no network), converted to depth and scored with every suite
exactly as a trained run is (run ``optimum/<variant>/w<weight>``)."""

from __future__ import annotations

import sys
from typing import Annotated

from msdepth.config.params import Params
from msdepth.data import kitti
from msdepth.data.index import read_eval_index
from msdepth.evaluation.results import run_suite
from msdepth.evaluation.suites import depth_maps, load_frames
from msdepth.io import save_npy, save_npz
from msdepth.optimum.frames import boxes_of, checked_weight, frame_disparities, optimum_run, sweep_frames
from msdepth.pipeline.paths import (
    EVAL_FRAMES,
    ROIS,
    SUITE_NAMES,
    VariantArg,
    depth_path,
    disparities_path,
    run_stage,
)


def optimum(
    params: Params,
    variant: VariantArg,
    weight: Annotated[str, "a smoothness weight listed in optimum.smoothness_sweep"],
) -> None:
    """Optimise, convert to depth, and run the full, ROI and gradient suites."""
    import torch

    value = checked_weight(params, weight)
    run = optimum_run(params.variant(variant), weight)
    torch.set_num_threads(params.optimum.threads)
    index = sweep_frames(params, read_eval_index(EVAL_FRAMES), value)
    disp = frame_disparities(params, variant, value, index)
    save_npy(disparities_path(run), disp)
    frames = load_frames(index)
    pred = depth_maps(disp, frames)
    save_npz(depth_path(run), **pred)
    boxes = boxes_of(kitti.read_rois(ROIS), [f.name for f in frames])
    for suite in SUITE_NAMES:
        run_suite(params, suite, run, pred, frames, None if suite == "full" else boxes)


if __name__ == "__main__":
    sys.exit(run_stage(optimum, *sys.argv[1:]))
