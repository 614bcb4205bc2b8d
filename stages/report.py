"""Stage ``report``: the numbers blocks of docs/results.md and the README, written from metrics/."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

from msdepth.config.params import Params
from msdepth.pipeline.paths import run_stage
from msdepth.reporting.report import write_report

log = logging.getLogger("msdepth")


def report(params: Params) -> None:
    """Rewrite the generated blocks of docs/results.md and, where README.md exists, of the README,
    from metrics/compare.json and metrics/train/ (the rest of both is written by hand: the README
    is not a DVC output, and docs/results.md is a persistent one)."""
    for path in write_report(Path(".")):
        log.info("wrote %s", path)


if __name__ == "__main__":
    sys.exit(run_stage(report, *sys.argv[1:]))
