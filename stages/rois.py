"""Stage: Validate the ROI boxes and write the ROI index."""

import sys

from msdepth.stages.common import run_stage
from msdepth.stages.rois import rois

if __name__ == "__main__":
    sys.exit(run_stage(rois, *sys.argv[1:]))
