"""Stage: Create the KITTI-format data tree (the synthetic set by default)."""

import sys

from msdepth.stages.common import run_stage
from msdepth.stages.prepare_data import prepare_data

if __name__ == "__main__":
    sys.exit(run_stage(prepare_data, *sys.argv[1:]))
