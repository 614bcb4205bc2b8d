"""Where each loss wants each ROI class: cost curves (msdepth.optimum.solver.cost_curve) on rendered frames.

The pipeline's ``cost_curves`` stage with the same functions (:mod:`msdepth.optimum.frames`), on
other frames and for several variants at once: for every ROI box of evaluation frames 0..N-1 of
the synthetic set, rendered here (no ``dvc repro`` needed), the variant's appearance cost of the
whole left view with the box's disparity at GT x s (s from 0.5 to 2) and the GT elsewhere; per
class the s of the lowest mean cost and its basin (docs/optimum.md). The GT is the render's exact
disparity (0 = sky, infinitely far), so every box counts (the stage keeps those with dense GT)::

    python studies/cost_curves.py --frames 4 --variants ssim msssim:3 msssim:11
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import pandas as pd

from msdepth.config.params import apply_overrides, kernel_variant, params_from_dict, read_params_file
from msdepth.errors import run_main
from msdepth.optimum.frames import add_cost_curves, cost_summary
from msdepth.render import render_frame

ROOT = Path(__file__).resolve().parents[1]  # its params.yaml is the base


def main(argv: list[str] | None = None) -> int:
    """Print a markdown table: per variant and ROI class, the s of the lowest mean cost and its basin."""
    from msdepth.optimum.solver import objective

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--variants", nargs="+", default=["ssim", "msssim:3"])
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args(argv)
    base = apply_overrides(read_params_file(ROOT / "params.yaml"), args.set)
    s = params_from_dict(base).data.synthetic
    frames = [render_frame(s.seed, 1, i, s.height, s.width) for i in range(args.frames)]
    rows = []
    for label in args.variants:
        name, raw = kernel_variant(base, label)
        criterion = objective(params_from_dict(raw), name)
        curves: dict[str, list] = {}
        for f in frames:
            boxes = [(cls, tuple(box)) for cls, *box in f.rois]
            add_cost_curves(curves, criterion, f.left, f.right, f.disp, boxes)
        for cls, summary in cost_summary(curves)["classes"].items():
            rows.append({"variant": label, "class": cls, **summary})
            print(json.dumps(rows[-1]), file=sys.stderr)
    print(pd.DataFrame(rows).to_markdown(index=False, floatfmt=".3f"))
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/cost_curves.py", main))
