"""Stage: decode and resize the training pairs once into data/cache/train_pairs.npy."""

import sys

from msdepth.stages.cache import cache
from msdepth.stages.common import run_stage

if __name__ == "__main__":
    sys.exit(run_stage(cache, *sys.argv[1:]))
