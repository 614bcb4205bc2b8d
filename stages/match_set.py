"""Stage ``match_set@<set>-<variant>`` and ``sgbm_set@<set>``: a classic stereo matcher on an extra
evaluation set's frames, no refinement, scored with the set's full-image and ROI suites: SGM on the
variant's own cost volume, the optimum's cost start (run ``optimum/match/<variant>``), or OpenCV's
SGBM (run ``optimum/sgbm``). Frame by frame, resumable; metrics only."""

from __future__ import annotations

import sys

from msdepth.config.params import Params
from msdepth.data.eval_index import set_index_path, set_rois_path
from msdepth.optimum.sets import score_set_match
from msdepth.pipeline.paths import INDEX_DIR, MatcherArg, SetArg, checked_set, run_stage


def match_set(params: Params, set_name: SetArg, matcher: MatcherArg) -> None:
    """Match every frame of an extra set, convert to depth, and run the set's suites."""
    name = checked_set(params, set_name)
    score_set_match(params, name, matcher, set_index_path(INDEX_DIR, name), set_rois_path(INDEX_DIR, name))


if __name__ == "__main__":
    sys.exit(run_stage(match_set, *sys.argv[1:]))
