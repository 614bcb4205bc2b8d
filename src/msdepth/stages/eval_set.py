"""Stage ``eval_set@<set>-<variant>-<seed>``: one run on an extra evaluation set (the Eigen split).

Inference, depth conversion and the full-image suite in one stage: a set's disparities serve
nothing else. The ROI suites stay on KITTI 2015, the set with boxes.
"""

from __future__ import annotations

from pathlib import Path

from ..config import Params
from ..data.index import read_eval_index, set_index_path
from ..evaluate import depth_maps, load_frames
from .common import INDEX_DIR, SeedArg, SetArg, VariantArg, checked_run, checked_set, model_path
from .evaluate import score_set


def eval_set(params: Params, set_name: SetArg, variant: VariantArg, seed: SeedArg) -> None:
    """Predict one run's depth on an extra evaluation set and score it with the full-image suite."""
    from ..infer import predict_disparities
    from ..train import load_model
    from .infer import torch_threads

    name, run = checked_set(params, set_name), checked_run(params, variant, seed)
    torch_threads(params)
    model, meta = load_model(model_path(run))
    index = read_eval_index(set_index_path(INDEX_DIR, name))
    frames = load_frames(index)
    disp = predict_disparities(
        model, [Path(p) for p in index["left"]], meta["height"], meta["width"], params.eval.post_process
    )
    score_set(params, name, run, depth_maps(disp, frames), frames)
