"""Stage: Convert one run's disparities to metric depth at GT resolution. Usage: depth.py VARIANT SEED"""

import sys

from msdepth.pipeline import depth, run_stage

if __name__ == "__main__":
    sys.exit(run_stage(depth, *sys.argv[1:]))
