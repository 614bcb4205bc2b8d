"""Stage ``eval_<suite>@<variant>-<seed>``: one evaluation suite on one run's depth maps."""

from __future__ import annotations

import sys
from typing import Annotated

from msdepth.config.params import Params
from msdepth.evaluation.results import checked_suite, score_run
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
    name = checked_suite(suite)
    run = checked_run(params, variant, seed)
    score_run(params, name, run, depth_path(run), EVAL_FRAMES, ROIS)


if __name__ == "__main__":
    sys.exit(run_stage(evaluate, *sys.argv[1:]))
