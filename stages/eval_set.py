"""Stage ``eval_set@<set>-<variant>-<seed>``: one run on an extra evaluation set (the Eigen split).

Inference, depth conversion and the full-image suite in one stage: a set's disparities serve
nothing else. The ROI suites stay on KITTI 2015, the set with boxes.
"""

from __future__ import annotations

import sys
from pathlib import Path

from msdepth.config.params import Params
from msdepth.data.index import read_eval_index, set_index_path
from msdepth.evaluation.results import median_scaling, score_set
from msdepth.evaluation.suites import depth_maps, load_frames
from msdepth.pipeline.paths import (
    INDEX_DIR,
    SeedArg,
    SetArg,
    VariantArg,
    checked_run,
    checked_set,
    model_path,
    run_stage,
)


def eval_set(params: Params, set_name: SetArg, variant: VariantArg, seed: SeedArg) -> None:
    """Predict one run's depth on an extra evaluation set and score it with the full-image suite."""
    import torch

    from msdepth.evaluation.infer import predict_disparities
    from msdepth.training.train import load_model

    name, run = checked_set(params, set_name), checked_run(params, variant, seed)
    torch.set_num_threads(params.train.threads)
    model, meta = load_model(model_path(run))
    index = read_eval_index(set_index_path(INDEX_DIR, name))
    frames = load_frames(index)
    disp = predict_disparities(
        model, [Path(p) for p in index["left"]], meta["height"], meta["width"], params.eval.post_process
    )
    pred = depth_maps(disp, frames, monocular=params.train.monocular)
    score_set(params, name, run, pred, frames, scaled=median_scaling(params))


if __name__ == "__main__":
    sys.exit(run_stage(eval_set, *sys.argv[1:]))
