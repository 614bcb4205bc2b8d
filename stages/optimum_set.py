"""Stage ``optimum_set@<set>-<variant>-<weight>``: the variant's own optimum disparity of an extra
evaluation set's frames at one weight of ``optimum.set_weights`` (no network), converted to depth
and scored with the set's full-image and ROI suites (run ``optimum/<variant>/w<weight>``, as on the
default frames). Frame by frame, resumable; metrics only."""

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
    weight: Annotated[str, "a weight of optimum.set_weights, as dvc.yaml writes it (the run's name)"],
) -> None:
    """Optimise every frame of an extra set, convert to depth, and run the set's suites."""
    name = checked_set(params, set_name)
    score_set_optimum(
        params, name, variant, weight, set_index_path(INDEX_DIR, name), set_rois_path(INDEX_DIR, name)
    )


if __name__ == "__main__":
    sys.exit(run_stage(optimum_set, *sys.argv[1:]))
