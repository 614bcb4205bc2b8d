"""Stage: Compare every variant and baseline side by side (Markdown + JSON)."""

import sys

from msdepth.pipeline import compare, run_stage

if __name__ == "__main__":
    sys.exit(run_stage(compare))
