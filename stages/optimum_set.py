"""Stage ``optimum_set@<set>-<variant>``: the variant's own optimum disparity of an extra
evaluation set's frames at ``optimum.smoothness_weight`` (no network), converted to depth and
scored with the set's full-image suite (run ``optimum/<variant>/w<weight>``, as on the default
frames). Frame by frame, resumable; metrics only."""

from __future__ import annotations

import sys
from typing import Annotated

from msdepth.config.params import Params
from msdepth.data.eval_index import set_index_path, set_rois_path
from msdepth.optimum.sets import score_set_optimum
from msdepth.pipeline.paths import INDEX_DIR, SetArg, VariantArg, checked_set, run_stage


def optimum_set(
    params: Params,
    set_name: SetArg,
    variant: VariantArg,
    weight: Annotated[str, "optimum.smoothness_weight, as dvc.yaml writes it (the run's name)"],
) -> None:
    """Optimise every frame of an extra set, convert to depth, and run the full-image suite."""
    name = checked_set(params, set_name)
    score_set_optimum(
        params, name, variant, weight, set_index_path(INDEX_DIR, name), set_rois_path(INDEX_DIR, name)
    )


if __name__ == "__main__":
    sys.exit(run_stage(optimum_set, *sys.argv[1:]))
