"""Stage ``cost_curves@<variant>``: the variant's appearance cost of every ROI with dense GT as
the box's disparity is scaled by s (GT outside), and per class the s of the lowest mean cost and
its basin (metrics/cost_curves/<variant>.json; not a DVC metric: a column per class and number
would make ``dvc metrics show`` unreadable)."""

from __future__ import annotations

import sys

from msdepth.config.params import Params
from msdepth.data import kitti
from msdepth.data.index import read_eval_index
from msdepth.io import write_json
from msdepth.optimum.frames import cost_summary, first_frames, roi_cost_curves
from msdepth.pipeline.paths import COST_CURVES, EVAL_FRAMES, ROIS, VariantArg, run_stage


def cost_curves(params: Params, variant: VariantArg) -> None:
    """Cost curves of every dense-GT ROI of the first optimum.cost_frames frames, per class."""
    import torch

    torch.set_num_threads(params.optimum.threads)
    curves = roi_cost_curves(
        params,
        params.variant(variant),
        first_frames(read_eval_index(EVAL_FRAMES), params.optimum.cost_frames),
        kitti.read_rois(ROIS),
    )
    write_json(COST_CURVES / f"{variant}.json", cost_summary(curves))


if __name__ == "__main__":
    sys.exit(run_stage(cost_curves, *sys.argv[1:]))
