"""Stage ``eval_<suite>@<variant>-<seed>``: one evaluation suite on one run's depth maps."""

from __future__ import annotations

import sys
from typing import Annotated

from msdepth.config.params import Params
from msdepth.data import kitti
from msdepth.data.index import read_eval_index
from msdepth.errors import ConfigError
from msdepth.evaluation.results import SUITES, run_suite
from msdepth.evaluation.suites import load_frames, read_depth_maps
from msdepth.pipeline.paths import (
    EVAL_FRAMES,
    ROIS,
    SUITE_NAMES,
    SeedArg,
    VariantArg,
    checked_run,
    depth_path,
    run_stage,
)


def evaluate(
    params: Params,
    suite: Annotated[str, f"the evaluation suite: {', '.join(SUITE_NAMES)}"],
    variant: VariantArg,
    seed: SeedArg,
) -> None:
    """Run one evaluation suite on one run's depth maps."""
    if suite not in SUITES:
        raise ConfigError(f"unknown evaluation suite {suite!r}; known: {sorted(SUITES)}")
    run = checked_run(params, variant, seed)
    frames = load_frames(read_eval_index(EVAL_FRAMES))
    boxes = kitti.read_rois(ROIS) if suite != "full" else None
    pred = read_depth_maps(depth_path(run))
    run_suite(params, suite, run, pred, frames, boxes, scaled=params.train.monocular)


if __name__ == "__main__":
    sys.exit(run_stage(evaluate, *sys.argv[1:]))
