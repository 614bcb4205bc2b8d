"""Stage ``depth@<variant>-<seed>``: one run's disparities as metric depth at GT resolution."""

from __future__ import annotations

import sys

import numpy as np

from msdepth.config.params import Params
from msdepth.data.index import read_eval_index
from msdepth.errors import DataError
from msdepth.evaluation.suites import depth_maps, load_frames
from msdepth.io import save_npz
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
    path = disparities_path(run)
    if not path.exists():
        raise DataError(f"{path}: no disparities for run {run!r}")
    frames = load_frames(read_eval_index(EVAL_FRAMES))
    save_npz(depth_path(run), **depth_maps(np.load(path), frames, monocular=params.train.monocular))


if __name__ == "__main__":
    sys.exit(run_stage(depth, *sys.argv[1:]))
