"""Stage: validate the whole params.yaml first, so that a bad value or an unknown key deletes nothing."""

import sys

from msdepth.stages.common import run_stage
from msdepth.stages.validate_params import validate_params

if __name__ == "__main__":
    sys.exit(run_stage(validate_params, *sys.argv[1:]))
