"""A trained run on an extra evaluation set (``eval.extra_sets``): inference, depth conversion and
the full-image suite (and the ROI suite on the set's boxes) in one step, as a set's disparities
serve nothing else."""

from __future__ import annotations

from pathlib import Path

from msdepth.config.params import Params
from msdepth.data.eval_index import read_eval_index
from msdepth.evaluation.infer import index_disparities
from msdepth.evaluation.results import median_scaling, score_set
from msdepth.evaluation.suites import depth_maps, load_frames
from msdepth.networks.model_file import DepthNetwork


def evaluate_on_set(
    params: Params,
    name: str,
    run: str,
    model: DepthNetwork,
    meta: dict,
    set_index: Path,
    rois: Path | None = None,
) -> None:
    """Run ``run``'s network ``model`` (``meta``: its model file's) on the frames of extra set
    ``name`` (its index ``set_index``) and score its depth with the full-image suite, median-scaled
    where :func:`~msdepth.evaluation.results.median_scaling` says; with ``rois`` (the set's ROI
    file), the ROI suite too (:func:`~msdepth.evaluation.results.score_set`)."""
    index = read_eval_index(set_index)
    frames = load_frames(index)
    disp = index_disparities(model, meta, index, params.eval.post_process)
    pred = depth_maps(disp, frames, monocular=params.train.monocular)
    score_set(params, name, run, pred, frames, scaled=median_scaling(params), rois=rois)
