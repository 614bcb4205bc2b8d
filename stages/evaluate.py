"""Stage: one evaluation suite on one run. Usage: evaluate.py {full,roi,gradients} VARIANT SEED"""

import sys

from msdepth.pipeline import evaluate, run_stage

if __name__ == "__main__":
    sys.exit(run_stage(evaluate, *sys.argv[1:]))
