"""Stage: Compare every variant and baseline side by side (Markdown + JSON)."""

import sys

from msdepth.stages.common import run_stage
from msdepth.stages.compare import compare

if __name__ == "__main__":
    sys.exit(run_stage(compare, *sys.argv[1:]))
