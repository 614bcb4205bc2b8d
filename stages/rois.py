"""Stage ``rois``: validate the ROI boxes and write the ROI indexes and their contact sheets."""

from __future__ import annotations

import sys

from msdepth.config.params import Params
from msdepth.data.eval_index import read_eval_index, set_index_path, set_rois_path
from msdepth.pipeline.paths import EVAL_FRAMES, INDEX_DIR, ROI_SHEET, ROIS, SET_ROIS, run_stage


def rois(params: Params) -> None:
    """The ROI boxes: the synthetic set's exact ones, KITTI's obj_map cars plus the user's CSV,
    or a stereo folder's data.folder.rois_csv. No ROI at all is allowed (the ROI suites say so).

    Writes the ROI index and a contact sheet of the crops (``data/index/rois.png``), then the same
    for each set of ``eval.extra_sets`` below ``data/index/set_rois/`` (KITTI 2015's obj_map cars
    and ``data.kitti.rois_csv``, KITTI 2012's ``data.kitti.kitti2012_rois_csv``, none on the Eigen
    sets), which the set stages score as objects.
    """
    from msdepth.data.rois import write_roi_index, write_set_rois

    write_roi_index(params, read_eval_index(EVAL_FRAMES), ROIS, ROI_SHEET)
    SET_ROIS.mkdir(parents=True, exist_ok=True)  # a DVC out even without extra sets
    for name in params.eval.extra_sets:
        frames = read_eval_index(set_index_path(INDEX_DIR, name))
        write_set_rois(params, name, frames, set_rois_path(INDEX_DIR, name))


if __name__ == "__main__":
    sys.exit(run_stage(rois, *sys.argv[1:]))
