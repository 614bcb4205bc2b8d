"""Stage: Convert one run's disparities to metric depth at GT resolution. Usage: depth.py VARIANT SEED"""

import sys

from msdepth.stages.common import run_stage
from msdepth.stages.depth import depth

if __name__ == "__main__":
    sys.exit(run_stage(depth, *sys.argv[1:]))
