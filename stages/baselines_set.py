"""Stage: Score the image-blind baselines on an extra evaluation set. Usage: baselines_set.py SET_NAME"""

import sys

from msdepth.stages.baselines_set import baselines_set
from msdepth.stages.common import run_stage

if __name__ == "__main__":
    sys.exit(run_stage(baselines_set, *sys.argv[1:]))
