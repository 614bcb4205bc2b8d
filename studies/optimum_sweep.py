"""The losses' own optimum on rendered evaluation frames, at several smoothness weights.

Renders evaluation frames of the synthetic set (:func:`msdepth.evaluation.rendered.rendered_eval_set`),
runs the optimum per variant and weight and scores it with the evaluation's suites (cap 80 m):
abs_rel and a1, ROI abs_rel per class (boxes and exact masks), D1 and EPE, beside an oracle
constant. ``--matchers`` adds SGM on each variant's cost volume and OpenCV's SGBM, unrefined;
``--trace`` prints the mean loss per level at steps 25, 50, 100, ... (the stopping rule's measure)::

    python studies/optimum_sweep.py --frames 8 --variants ssim msssim:3 --weights 0.3 1 3
    python studies/optimum_sweep.py --frames 8 --weights 10 --matchers --set optimum.iterations=50
    python studies/optimum_sweep.py --frames 4 --variants ssim msssim:3 --weights 1 \\
        --set optimum.iterations=200 --trace
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from msdepth.config.params import (
    MAX_WEIGHT,
    apply_overrides,
    kernel_variant,
    params_from_dict,
    read_params_file,
)
from msdepth.errors import ConfigError, run_main
from msdepth.evaluation.rendered import rendered_eval_set
from msdepth.evaluation.suites import Frame, depth_maps, evaluate_full, evaluate_roi

ROOT = Path(__file__).resolve().parents[1]  # its params.yaml is the base
CAP = "cap80"


def scores(disps: list[np.ndarray], frames: list[Frame], rois: pd.DataFrame, params) -> dict:
    """Full-frame abs_rel/a1 and per-class ROI abs_rel (boxes, masks) at cap 80 m."""
    pred = depth_maps(disps, frames)
    full, _ = evaluate_full(pred, frames, params.eval)
    roi, _ = evaluate_roi(pred, frames, rois, params.eval)
    out = {"abs_rel": full[CAP]["abs_rel"], "a1": full[CAP]["a1"]}
    out.update({"D1 %": 100 * full[CAP]["d1"], "EPE px": full[CAP]["epe"]})
    for cls, m in roi[CAP]["by_class"].items():
        out[f"box {cls}"] = m["abs_rel"]
    for cls, m in roi.get("masks", {}).get(CAP, {}).get("by_class", {}).items():
        out[f"mask {cls}"] = m["abs_rel"]
    return out


def matcher_rows(
    base: dict, variants: list[str], pairs: list, frames: list[Frame], rois: pd.DataFrame
) -> list:
    """SGM on each variant's own cost volume, then SGBM: each pair matched at its own size, unrefined."""
    from msdepth.optimum.starts import matched_disparity

    rows = []
    for label, start in [*((v, "cost") for v in variants), ("SGBM", "sgbm")]:
        name, raw = kernel_variant(base, "ssim" if start == "sgbm" else label)
        p = params_from_dict(raw)
        clock = time.perf_counter()
        disps = [matched_disparity(left, right, p, name, start) / left.shape[1] for left, right in pairs]
        seconds = (time.perf_counter() - clock) / len(pairs)
        run = label if start == "sgbm" else f"SGM {label}"
        rows.append({"run": run, "weight": "", "s/pair": round(seconds, 2), **scores(disps, frames, rois, p)})
        print(json.dumps(rows[-1]), file=sys.stderr)
    return rows


def main(argv: list[str] | None = None) -> int:
    from msdepth.optimum.solver import objective, optimise, optimum_disparities

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--variants", nargs="+", default=["ssim", "msssim:3"])
    ap.add_argument("--weights", nargs="+", type=float, default=None, help="default: the sweep")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--trace", action="store_true", help="print the mean loss per level at steps 25, 50, ...")
    ap.add_argument("--matchers", action="store_true", help="add SGM on each variant's cost and SGBM")
    args = ap.parse_args(argv)
    if args.frames < 1:
        raise ConfigError(f"--frames: must be at least 1, got {args.frames}")
    if args.weights and not all(0 <= w <= MAX_WEIGHT for w in args.weights):  # NaN too
        raise ConfigError(f"--weights: each must be in [0, {MAX_WEIGHT:g}], got {args.weights}")
    base = apply_overrides(read_params_file(ROOT / "params.yaml"), args.set)
    params = params_from_dict(base)
    # The frames the pipeline evaluates: through its camera (data.synthetic.camera).
    s = params.data.synthetic
    rendered = rendered_eval_set(s, args.frames, s.camera)
    pairs, frames, rois = rendered.pairs, rendered.frames, rendered.rois
    weights = args.weights or list(params.optimum.smoothness_sweep)
    # The oracle constant: median GT disparity, as a fraction of the width (depth_maps' input).
    constant = [
        np.full(f.shape, np.median(f.focal * f.baseline / f.gt_depth[f.valid]) / f.shape[1], np.float32)
        for f in frames
    ]
    rows = [{"run": "oracle constant", "weight": "", **scores(constant, frames, rois, params)}]
    if args.matchers:
        rows += matcher_rows(base, args.variants, pairs, frames, rois)
    for label in args.variants:
        name, raw = kernel_variant(base, label)
        p = params_from_dict(raw)
        for w in weights:
            start = time.perf_counter()
            disps = optimum_disparities(pairs, p, name, w, progress=False)
            seconds = (time.perf_counter() - start) / len(pairs)
            row = {"run": label, "weight": w, "s/pair": round(seconds, 2)}
            rows.append({**row, **scores(disps, frames, rois, p)})
            print(json.dumps(rows[-1]), file=sys.stderr)
        if args.trace:
            import torch

            from msdepth.data.pairs import to_tensor

            trace: list = []
            left = torch.stack([to_tensor(a) for a, _ in pairs])
            right = torch.stack([to_tensor(b) for _, b in pairs])
            optimise(left, right, objective(p, name), p.optimum, trace)
            for level, steps in enumerate(trace):
                # Steps 25, 50, 100, ... that the level reached; a shorter level, its last step.
                marks = [n for n in (25, 50, 100, 200, 400, 800) if n <= len(steps)] or [len(steps)]
                losses = ", ".join(f"{n}: {steps[n - 1] / len(pairs):.5f}" for n in marks)
                print(f"{label} level {level}: {losses}")
    print(pd.DataFrame(rows).to_markdown(index=False, floatfmt=".3f"))
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/optimum_sweep.py", main))
