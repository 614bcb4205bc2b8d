"""Stage: Score a trained run on an extra evaluation set (Eigen). Usage: eval_set.py SET_NAME VARIANT SEED"""

import sys

from msdepth.stages.common import run_stage
from msdepth.stages.eval_set import eval_set

if __name__ == "__main__":
    sys.exit(run_stage(eval_set, *sys.argv[1:]))
