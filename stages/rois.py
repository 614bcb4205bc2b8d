"""Stage ``rois``: validate the ROI boxes and write the ROI index and its contact sheet."""

from __future__ import annotations

import sys

from msdepth.config.params import Params
from msdepth.data.eval_index import read_eval_index
from msdepth.pipeline.paths import EVAL_FRAMES, ROI_SHEET, ROIS, run_stage


def rois(params: Params) -> None:
    """The ROI boxes: the synthetic set's exact ones, KITTI's obj_map cars plus the user's CSV,
    or a stereo folder's data.folder.rois_csv. No ROI at all is allowed (the ROI suites say so).

    Writes the ROI index and a contact sheet of the crops (``data/index/rois.png``).
    """
    from msdepth.data.rois import write_roi_index

    write_roi_index(params, read_eval_index(EVAL_FRAMES), ROIS, ROI_SHEET)


if __name__ == "__main__":
    sys.exit(run_stage(rois, *sys.argv[1:]))
