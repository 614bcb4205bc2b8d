"""Stage ``eval_set@<set>-<variant>-<seed>``: one run on an extra evaluation set (the Eigen split).

Inference, depth conversion, the full-image suite and the ROI suite on the set's boxes
(``data/index/set_rois/<set>.csv``, each box a unit) in one stage: a set's disparities serve
nothing else.
"""

from __future__ import annotations

import sys

from msdepth.config.params import Params
from msdepth.data.eval_index import set_index_path, set_rois_path
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

    from msdepth.evaluation.extra_sets import evaluate_on_set
    from msdepth.training.train import load_model

    name, run = checked_set(params, set_name), checked_run(params, variant, seed)
    torch.set_num_threads(params.train.threads)
    model, meta = load_model(model_path(run))
    evaluate_on_set(
        params, name, run, model, meta, set_index_path(INDEX_DIR, name), set_rois_path(INDEX_DIR, name)
    )


if __name__ == "__main__":
    sys.exit(run_stage(eval_set, *sys.argv[1:]))
