"""Stage ``baselines_set@<set>``: the image-blind baselines on an extra evaluation set."""

from __future__ import annotations

from .. import baselines as baselines_mod
from ..config import Params
from ..data.index import read_eval_index, set_index_path
from ..evaluate import depth_maps, load_frames
from .baselines import BASELINES, skip_reason, training_gt, write_skipped
from .common import INDEX_DIR, SETS_METRICS, SetArg, checked_set
from .evaluate import score_set


def baselines_set(params: Params, set_name: SetArg) -> None:
    """The constant and per-pixel prior of the training GT, scored on an extra set's full images
    (skipped, with the reason in their JSON, when no training frame has GT)."""
    name = checked_set(params, set_name)
    gt = training_gt()
    if gt.maps is None:
        reason = skip_reason(gt)
        for run in BASELINES:
            write_skipped(
                SETS_METRICS / name, "full", run, reason, headline=True, headline_root=f"sets/{name}"
            )
        return
    frames = load_frames(read_eval_index(set_index_path(INDEX_DIR, name)))
    for run, disp in baselines_mod.baseline_disparities(gt.maps, len(frames)).items():
        score_set(params, name, run, depth_maps(disp, frames), frames)
