"""Stage ``rois``: validate the ROI boxes and write the ROI index and its contact sheet."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

from msdepth.config.params import Params
from msdepth.data import kitti
from msdepth.data.index import read_eval_index
from msdepth.data.layout import folder_layout, layout
from msdepth.errors import DataError
from msdepth.pipeline.paths import EVAL_FRAMES, ROI_SHEET, ROIS, run_stage

log = logging.getLogger("msdepth")


def rois(params: Params) -> None:
    """The ROI boxes: the synthetic set's exact ones, KITTI's obj_map cars plus the user's CSV,
    or a stereo folder's data.folder.rois_csv. No ROI at all is allowed (the ROI suites say so).

    Writes the ROI index and a contact sheet of the crops (``data/index/rois.png``).
    """
    from msdepth.data.rois import contact_sheet, extract_rois

    frames = read_eval_index(EVAL_FRAMES)
    if params.data.source == "folder":  # the user's boxes only: a folder has no obj_map
        user = folder_layout(params).rois_csv
        boxes = extract_rois(frames, user_csv=user)
    elif (source := layout(params).rois) is not None:
        boxes = kitti.read_rois(source)
        unknown = sorted(set(boxes["image"]) - set(frames["frame"]))
        if unknown:
            raise DataError(f"{source}: boxes name images that are not evaluation frames: {unknown[:10]}")
    else:  # extract_rois checks the user's boxes against the frames itself
        k = params.data.kitti
        boxes = extract_rois(
            frames,
            user_csv=Path(k.rois_csv) if k.rois_csv else None,
            min_size=k.roi_min_size,
            min_valid=k.roi_min_valid,
        )
    if boxes.empty:  # the ROI suites then write an explicit "no ROIs" summary
        log.warning(
            "rois: no ROI (%s): the ROI and gradient suites will be skipped",
            "no data.folder.rois_csv"
            if params.data.source == "folder"
            else "no car in any obj_map passed data.kitti.roi_min_size/roi_min_valid, "
            "and no data.kitti.rois_csv",
        )
    kitti.write_rois(ROIS, boxes)
    contact_sheet(boxes, frames, ROI_SHEET)
    log.info("rois: %d boxes, %s", len(boxes), boxes["class"].value_counts().to_dict())


if __name__ == "__main__":
    sys.exit(run_stage(rois, *sys.argv[1:]))
