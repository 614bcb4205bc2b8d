"""Stage ``cost_curves@<variant>``: the variant's appearance cost of every ROI with dense GT as
the box's disparity is scaled by s (GT outside), and per class the s of the lowest mean cost and
its basin (metrics/cost_curves/<variant>.json; not a DVC metric: a column per class and number
would make ``dvc metrics show`` unreadable)."""

from __future__ import annotations

import sys

from msdepth.config.params import Params
from msdepth.optimum.frames import write_cost_curves
from msdepth.pipeline.paths import EVAL_FRAMES, ROIS, VariantArg, cost_curves_path, run_stage


def cost_curves(params: Params, variant: VariantArg) -> None:
    """Cost curves of every dense-GT ROI of the first optimum.cost_frames frames, per class."""
    write_cost_curves(params, variant, EVAL_FRAMES, ROIS, cost_curves_path(variant))


if __name__ == "__main__":
    sys.exit(run_stage(cost_curves, *sys.argv[1:]))
