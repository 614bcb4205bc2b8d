"""Stage: Index the training pairs and evaluation frames found on disk."""

import sys

from msdepth.stages.common import run_stage
from msdepth.stages.index import index

if __name__ == "__main__":
    sys.exit(run_stage(index, *sys.argv[1:]))
