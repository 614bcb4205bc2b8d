"""Stage ``optimum@<variant>-<weight>``: the variant's own optimum disparity of the evaluation
frames at one smoothness weight (no network), converted to depth and scored with every suite
exactly as a trained run is (run ``optimum/<variant>/w<weight>``)."""

from __future__ import annotations

import sys
from typing import Annotated

from msdepth.config.params import Params
from msdepth.optimum.frames import checked_weight, score_optimum
from msdepth.pipeline.paths import (
    EVAL_FRAMES,
    ROIS,
    VariantArg,
    depth_path,
    disparities_path,
    optimum_run,
    run_stage,
)


def optimum(
    params: Params,
    variant: VariantArg,
    weight: Annotated[str, "a smoothness weight listed in optimum.smoothness_sweep"],
) -> None:
    """Optimise, convert to depth, and run the full, ROI and gradient suites."""
    value = checked_weight(params, weight)
    run = optimum_run(params.variant(variant), weight)
    score_optimum(
        params,
        variant,
        value,
        run,
        EVAL_FRAMES,
        ROIS,
        disparities=disparities_path(run),
        depth=depth_path(run),
    )


if __name__ == "__main__":
    sys.exit(run_stage(optimum, *sys.argv[1:]))
