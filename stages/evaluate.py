"""Stage: one evaluation suite on one run. Usage: evaluate.py {full,roi,gradients} VARIANT SEED"""

import sys

from msdepth.stages.common import run_stage
from msdepth.stages.evaluate import evaluate

if __name__ == "__main__":
    sys.exit(run_stage(evaluate, *sys.argv[1:]))
