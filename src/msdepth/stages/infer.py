"""Stage ``infer@<variant>-<seed>``: one run's disparities of every evaluation frame."""

from __future__ import annotations

from pathlib import Path

from ..config import Params
from ..data.index import read_eval_index
from ..io import save_npy
from .common import INDEX_DIR, SeedArg, VariantArg, checked_run, model_path, run_dir


def infer(params: Params, variant: VariantArg, seed: SeedArg) -> None:
    """Left disparities of every evaluation frame, at the network's input size."""
    from ..infer import predict_disparities
    from ..train import load_model

    run = checked_run(params, variant, seed)
    torch_threads(params)
    model, meta = load_model(model_path(run))
    frames = read_eval_index(INDEX_DIR / "eval_frames.csv")
    disp = predict_disparities(
        model, [Path(p) for p in frames["left"]], meta["height"], meta["width"], params.eval.post_process
    )
    save_npy(run_dir(run) / "disparities.npy", disp)


def torch_threads(params: Params) -> None:
    import torch

    torch.set_num_threads(params.train.threads)
