"""Stage ``match@<variant>`` and ``sgbm``: a classic stereo matcher on the evaluation frames, no
refinement, converted to depth and scored with every suite as a trained run is: SGM on the
variant's own cost volume (run ``optimum/match/<variant>``) or OpenCV's SGBM (run
``optimum/sgbm``). Metrics only; the rows beside the losses' own optimum in compare.md."""

from __future__ import annotations

import sys

from msdepth.config.params import Params
from msdepth.optimum.frames import score_match
from msdepth.pipeline.paths import EVAL_FRAMES, ROIS, MatcherArg, run_stage


def match(params: Params, matcher: MatcherArg) -> None:
    """Match every evaluation frame, convert to depth, and run the full, ROI and gradient suites."""
    score_match(params, matcher, EVAL_FRAMES, ROIS)


if __name__ == "__main__":
    sys.exit(run_stage(match, *sys.argv[1:]))
