"""Where each loss wants each ROI class: cost curves (msdepth.optimum.solver.cost_curve) on rendered frames.

For every ROI box of evaluation frames 0..N-1 of the synthetic set, the variant's appearance cost
of the whole left view with the box's disparity at GT x s (s from 0.5 to 2) and the GT elsewhere;
per class the s of the lowest mean cost and its basin (docs/optimum.md). The GT is the render's
exact disparity (0 = sky, infinitely far)::

    python studies/cost_curves.py --frames 4 --variants ssim msssim:3 msssim:11
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import pandas as pd
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))  # optimum_sweep, beside this script

from optimum_sweep import ROOT, variant_params  # noqa: E402

from msdepth.config.params import apply_overrides, params_from_dict  # noqa: E402
from msdepth.data.pairs import to_tensor  # noqa: E402
from msdepth.data.synthetic import render_frame  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    from msdepth.optimum.solver import class_summary, cost_curve, objective

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--variants", nargs="+", default=["ssim", "msssim:3"])
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args(argv)
    base = apply_overrides(yaml.safe_load((ROOT / "params.yaml").read_text()), args.set)
    s = params_from_dict(base).data.synthetic
    frames = [render_frame(s.seed, 1, i, s.height, s.width) for i in range(args.frames)]
    rows = []
    for spec in args.variants:
        label, name, params = variant_params(base, spec)
        criterion = objective(params, name)
        curves: dict[str, list] = {}
        for f in frames:
            left, right = to_tensor(f.left), to_tensor(f.right)
            for cls, *box in f.rois:
                curves.setdefault(cls, []).append(cost_curve(left, right, f.disp, tuple(box), criterion))
        for cls, summary in class_summary(curves).items():
            rows.append({"variant": label, "class": cls, **summary})
            print(json.dumps(rows[-1]), file=sys.stderr)
    print(pd.DataFrame(rows).to_markdown(index=False, floatfmt=".3f"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
