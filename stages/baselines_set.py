"""Stage ``baselines_set@<set>``: the image-blind baselines on an extra evaluation set."""

from __future__ import annotations

import sys

from msdepth.config.params import Params
from msdepth.data.index import read_eval_index, set_index_path
from msdepth.evaluation import baselines as baselines_mod
from msdepth.evaluation.results import score_set
from msdepth.evaluation.suites import depth_maps, load_frames
from msdepth.pipeline.paths import INDEX_DIR, SETS_METRICS, SetArg, checked_set, run_stage


def baselines_set(params: Params, set_name: SetArg) -> None:
    """The constant and per-pixel prior of the training GT, scored on an extra set's full images
    (skipped, with the reason in their JSON, when no training frame has GT)."""
    name = checked_set(params, set_name)
    gt = baselines_mod.indexed_training_gt()
    if gt.maps is None:
        reason = baselines_mod.skip_reason(gt)
        for run in baselines_mod.BASELINES:
            baselines_mod.write_skipped(
                SETS_METRICS / name, "full", run, reason, headline=True, headline_root=f"sets/{name}"
            )
        return
    frames = load_frames(read_eval_index(set_index_path(INDEX_DIR, name)))
    for run, disp in baselines_mod.baseline_disparities(gt.maps, len(frames)).items():
        score_set(params, name, run, depth_maps(disp, frames), frames)


if __name__ == "__main__":
    sys.exit(run_stage(baselines_set, *sys.argv[1:]))
