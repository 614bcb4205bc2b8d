"""Stage: Train one loss variant. Usage: train.py VARIANT SEED"""

import sys

from msdepth.stages.common import run_stage
from msdepth.stages.train import train

if __name__ == "__main__":
    sys.exit(run_stage(train, *sys.argv[1:]))
