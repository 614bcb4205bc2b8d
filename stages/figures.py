"""Stage: Draw the dissertation's figures under plots/figures/."""

import sys

from msdepth.pipeline import figures, run_stage

if __name__ == "__main__":
    sys.exit(run_stage(figures))
