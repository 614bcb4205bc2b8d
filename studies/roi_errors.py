"""Where do the ROI errors come from? Per class, each run's depth against the GT's and the prior's.

Issue 17's goal 3 asks the networks to beat the image-blind constant on every ROI class. This
study says why they do not: for every ROI (box) of the evaluation frames it takes the median
predicted depth of a run (``outputs/<run>/depth.npz``, from ``dvc repro``), the median of the
image-blind per-pixel prior's depth (:func:`msdepth.evaluation.baselines.baseline_disparities`) and the
median GT depth, over the box's valid GT pixels (cap 80 m), and reports per class and box size
at the network's input: the median ratio prediction / GT (> 1: too far), the prior's ratio, and
the correlation over boxes of log(prediction / GT) with log(prior / GT). A correlation near 1
with ratios alike means the network places that class where the prior would: from the image
position, not from the stereo cue.

Run from the repository root after ``dvc repro``::

    python studies/roi_errors.py --runs ssim/seed0 msssim/seed0 --out studies/results/roi_errors.md
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from msdepth.config.params import load_params
from msdepth.data import kitti
from msdepth.data.eval_index import read_eval_index
from msdepth.data.pairs import load_pair_list
from msdepth.errors import run_main
from msdepth.evaluation import baselines
from msdepth.evaluation.suites import depth_maps, load_frames, read_depth_maps
from msdepth.io import write_text
from msdepth.outputs import claim_output_file

INDEX = Path("data/index")
CAP = 80.0
MIN_DEPTH = 1e-3


def box_medians(depth: dict[str, np.ndarray], frames: dict, boxes) -> list[tuple[float, float]]:
    """Per box: (median depth, median GT) over its GT pixels in (0, CAP]; NaN where it has none."""
    out = []
    for box in boxes.itertuples():
        gt = frames[box.image].gt_depth[box.y0 : box.y1, box.x0 : box.x1]
        pred = np.clip(depth[box.image][box.y0 : box.y1, box.x0 : box.x1], MIN_DEPTH, CAP)
        valid = (gt > 0) & (gt <= CAP)
        out.append(
            (float(np.median(pred[valid])), float(np.median(gt[valid]))) if valid.any() else (np.nan,) * 2
        )
    return out


def report(runs: list[str], min_height: float) -> str:
    """The markdown table: per run and class (and small / large boxes), ratios and correlations."""
    params = load_params("params.yaml")
    index = read_eval_index(INDEX / "eval_frames.csv")
    frame_list = load_frames(index)
    frames = {f.name: f for f in frame_list}
    boxes = kitti.read_rois(INDEX / "rois.csv")
    pairs = load_pair_list(INDEX / "train_pairs.txt")
    gt_maps = baselines.training_gt([left for left, _ in pairs], progress=False).maps
    prior = depth_maps(baselines.baseline_disparities(gt_maps, len(frame_list))["prior"], frame_list)
    prior_med = np.array(box_medians(prior, frames, boxes))
    scale = params.data.height / next(iter(frames.values())).shape[0]
    large = (boxes["y1"] - boxes["y0"]).to_numpy() * scale >= min_height
    lines = [
        f"Boxes of at least {min_height:g} px in height at the network's input "
        f"({params.data.height} x {params.data.width}) are 'large'. Ratios: median of "
        "(box median depth) / (box median GT); corr: over boxes, of log(run / GT) with log(prior / GT).",
        "",
        "| run | class | boxes | GT median (m) | run / GT | prior / GT | corr. with prior |",
        "|---|---|---|---|---|---|---|",
    ]
    for run in runs:
        med = np.array(box_medians(read_depth_maps(Path("outputs") / run / "depth.npz"), frames, boxes))
        for cls in sorted(boxes["class"].unique()):
            for size, pick in (("small", ~large), ("large", large)):
                sel = (boxes["class"].to_numpy() == cls) & pick & np.isfinite(med[:, 0])
                if sel.sum() < 3:
                    continue
                ours, theirs = (
                    np.log(med[sel, 0] / med[sel, 1]),
                    np.log(prior_med[sel, 0] / prior_med[sel, 1]),
                )
                lines.append(
                    f"| {run} | {cls} ({size}) | {sel.sum()} | {np.median(med[sel, 1]):.1f} | "
                    f"{np.exp(np.median(ours)):.2f} | {np.exp(np.median(theirs)):.2f} | "
                    f"{np.corrcoef(ours, theirs)[0, 1]:.2f} |"
                )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", nargs="+", default=["ssim/seed0", "msssim/seed0"])
    ap.add_argument("--min-height", type=float, default=4.0, help="px at the network's input")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    if not claim_output_file(args.out, "roi-errors", "outputs"):  # before the work
        return 1
    text = report(args.runs, args.min_height)
    if args.out:
        write_text(args.out, text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/roi_errors.py", main))
