"""Stage: Train one loss variant. Usage: train.py VARIANT SEED"""

import sys

from msdepth.pipeline import run_stage, train

if __name__ == "__main__":
    sys.exit(run_stage(train, *sys.argv[1:]))
