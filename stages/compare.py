"""Stage ``compare``: every variant (mean over its seeds) and baseline side by side, Markdown + JSON."""

from __future__ import annotations

import sys

from msdepth.config.params import Params
from msdepth.pipeline.paths import run_stage
from msdepth.reporting import pipeline_compare


def compare(params: Params) -> None:
    """One table of every variant (mean over its seeds) and baseline, as Markdown and JSON.

    A baseline the baselines stage could not build is listed as missing, with the reason.
    """
    pipeline_compare.write_comparison(params)


if __name__ == "__main__":
    sys.exit(run_stage(compare, *sys.argv[1:]))
