"""Stage: Evaluate the image-blind baselines (constant, per-pixel prior) with all suites."""

import sys

from msdepth.stages.baselines import baselines
from msdepth.stages.common import run_stage

if __name__ == "__main__":
    sys.exit(run_stage(baselines, *sys.argv[1:]))
