"""Stage ``figures``: the dissertation's figures under plots/figures/."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

from msdepth.config.params import Params
from msdepth.pipeline.paths import COST_CURVES, run_stage, variant_runs

log = logging.getLogger("msdepth")


def figures(params: Params) -> None:
    """The dissertation's figures (disparities, ROI depth and gradients, curves, error scatter)."""
    from msdepth.reporting.figures import (
        COST_CURVES_FIGURE,
        cost_curve_figure,
        make_figures,
        read_cost_curves,
    )

    # The first seed's run of each variant: the figures show predictions, not an average of
    # them; the training curves show every seed's.
    groups = variant_runs(params)
    paths = make_figures(
        {v: runs[0] for v, runs in groups.items()},
        Path("plots") / "figures",
        eval_cfg=params.eval,
        curves=groups,
    )
    # The cost_curves stage's summaries: the losses' own preference per ROI class.
    paths.append(
        cost_curve_figure(
            read_cost_curves(COST_CURVES, params.variants), Path("plots/figures") / COST_CURVES_FIGURE
        )
    )
    log.info("figures: %s", ", ".join(p.name for p in paths))


if __name__ == "__main__":
    sys.exit(run_stage(figures, *sys.argv[1:]))
