"""Stage: decode and resize the training pairs once into data/cache/train_pairs.npy."""

import sys

from msdepth.pipeline import cache, run_stage

if __name__ == "__main__":
    sys.exit(run_stage(cache))
