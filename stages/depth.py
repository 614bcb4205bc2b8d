"""Stage ``depth@<variant>-<seed>``: one run's disparities as metric depth at GT resolution."""

from __future__ import annotations

import sys

import numpy as np

from msdepth.config import Params
from msdepth.data.index import read_eval_index
from msdepth.errors import DataError
from msdepth.evaluate import depth_maps, load_frames
from msdepth.io import save_npz
from msdepth.pipeline import INDEX_DIR, SeedArg, VariantArg, checked_run, run_dir, run_stage


def depth(params: Params, variant: VariantArg, seed: SeedArg) -> None:
    """Disparities (fraction of width) -> metric depth at each frame's GT resolution."""
    run = checked_run(params, variant, seed)
    path = run_dir(run) / "disparities.npy"
    if not path.exists():
        raise DataError(f"{path}: no disparities for run {run!r}")
    frames = load_frames(read_eval_index(INDEX_DIR / "eval_frames.csv"))
    save_npz(run_dir(run) / "depth.npz", **depth_maps(np.load(path), frames))


if __name__ == "__main__":
    sys.exit(run_stage(depth, *sys.argv[1:]))
