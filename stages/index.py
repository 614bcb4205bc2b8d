"""Stage: Index the training pairs and evaluation frames found on disk."""

import sys

from msdepth.pipeline import index, run_stage

if __name__ == "__main__":
    sys.exit(run_stage(index))
