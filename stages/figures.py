"""Stage ``figures``: the dissertation's figures under plots/figures/."""

from __future__ import annotations

import sys

from msdepth.config.params import Params
from msdepth.pipeline.paths import COST_CURVES, FIGURES_DIR, run_stage


def figures(params: Params) -> None:
    """The dissertation's figures (disparities, ROI depth and gradients, curves, error scatter)."""
    from msdepth.reporting.figures import pipeline_figures

    pipeline_figures(params, FIGURES_DIR, COST_CURVES)


if __name__ == "__main__":
    sys.exit(run_stage(figures, *sys.argv[1:]))
