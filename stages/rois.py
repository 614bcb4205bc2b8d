"""Stage: Validate the ROI boxes and write the ROI index."""

import sys

from msdepth.pipeline import rois, run_stage

if __name__ == "__main__":
    sys.exit(run_stage(rois))
