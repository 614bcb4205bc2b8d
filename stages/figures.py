"""Stage: Draw the dissertation's figures under plots/figures/."""

import sys

from msdepth.stages.common import run_stage
from msdepth.stages.figures import figures

if __name__ == "__main__":
    sys.exit(run_stage(figures, *sys.argv[1:]))
