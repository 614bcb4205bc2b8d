"""Stage ``infer@<variant>-<seed>``: one run's disparities of every evaluation frame."""

from __future__ import annotations

import sys

from msdepth.config.params import Params
from msdepth.data.eval_index import read_eval_index
from msdepth.io import save_npy
from msdepth.pipeline.paths import (
    EVAL_FRAMES,
    SeedArg,
    VariantArg,
    checked_run,
    disparities_path,
    model_path,
    run_stage,
)


def infer(params: Params, variant: VariantArg, seed: SeedArg) -> None:
    """Left disparities of every evaluation frame, at the network's input size."""
    import torch

    from msdepth.evaluation.infer import index_disparities
    from msdepth.training.train import load_model

    run = checked_run(params, variant, seed)
    torch.set_num_threads(params.train.threads)
    model, meta = load_model(model_path(run))
    disp = index_disparities(model, meta, read_eval_index(EVAL_FRAMES), params.eval.post_process)
    save_npy(disparities_path(run), disp)


if __name__ == "__main__":
    sys.exit(run_stage(infer, *sys.argv[1:]))
