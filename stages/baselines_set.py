"""Stage ``baselines_set@<set>``: the image-blind baselines on an extra evaluation set."""

from __future__ import annotations

import sys

from msdepth.config.params import Params
from msdepth.data.eval_index import set_index_path, set_rois_path
from msdepth.evaluation.baselines import score_set_baselines
from msdepth.pipeline.paths import INDEX_DIR, TRAIN_PAIRS, SetArg, checked_set, run_stage


def baselines_set(params: Params, set_name: SetArg) -> None:
    """The constant and per-pixel prior of the training GT, scored on an extra set's full images
    (skipped, with the reason in their JSON, when no training frame has GT)."""
    name = checked_set(params, set_name)
    score_set_baselines(
        params, name, TRAIN_PAIRS, set_index_path(INDEX_DIR, name), set_rois_path(INDEX_DIR, name)
    )


if __name__ == "__main__":
    sys.exit(run_stage(baselines_set, *sys.argv[1:]))
