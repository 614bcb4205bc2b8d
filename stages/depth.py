"""Stage ``depth@<variant>-<seed>``: one run's disparities as metric depth at GT resolution."""

from __future__ import annotations

import sys

from msdepth.config.params import Params
from msdepth.evaluation.results import write_depth_maps
from msdepth.pipeline.paths import (
    EVAL_FRAMES,
    SeedArg,
    VariantArg,
    checked_run,
    depth_path,
    disparities_path,
    run_stage,
)


def depth(params: Params, variant: VariantArg, seed: SeedArg) -> None:
    """Disparities (fraction of width) -> depth at each frame's GT resolution: metric, or a
    monocular run's (train.mode mono | mono_stereo) up to scale."""
    run = checked_run(params, variant, seed)
    write_depth_maps(
        run, disparities_path(run), EVAL_FRAMES, depth_path(run), monocular=params.train.monocular
    )


if __name__ == "__main__":
    sys.exit(run_stage(depth, *sys.argv[1:]))
