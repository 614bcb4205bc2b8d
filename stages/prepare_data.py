"""Stage: Create the KITTI-format data tree (the synthetic set by default)."""

import sys

from msdepth.pipeline import prepare_data, run_stage

if __name__ == "__main__":
    sys.exit(run_stage(prepare_data))
