"""Stage: Predict the evaluation frames' disparities with one trained variant. Usage: infer.py VARIANT SEED"""

import sys

from msdepth.stages.common import run_stage
from msdepth.stages.infer import infer

if __name__ == "__main__":
    sys.exit(run_stage(infer, *sys.argv[1:]))
