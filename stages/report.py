"""Stage ``report``: docs/results.md and the README's headline block, written from metrics/."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

from msdepth.config.params import Params
from msdepth.pipeline.paths import run_stage
from msdepth.reporting.report import write_report

log = logging.getLogger("msdepth")


def report(params: Params) -> None:
    """Render docs/results.md and, where README.md exists, its block between the report markers,
    from metrics/compare.json and metrics/train/ (the README is not a DVC output: the rest of it
    is written by hand, so the stage rewrites only its own block)."""
    for path in write_report(Path(".")):
        log.info("wrote %s", path)


if __name__ == "__main__":
    sys.exit(run_stage(report, *sys.argv[1:]))
