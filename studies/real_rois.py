"""The hand-drawn ROIs on the real KITTI 2015 frames (issue 39, item 3): their GT density, an
overlay picture of each frame, and a sanity score of OpenCV's SGBM inside them.

Reads ``data_lists/kitti2015_rois.csv`` (:func:`msdepth.data.annotations.read_annotation`) and the frames of
``../shared/real-samples/kitti2015-training`` (left and right images, ``disp_occ_0`` GT). For each
box: the share of its pixels with GT. For each class: the ROI suite
(:func:`msdepth.evaluation.suites.evaluate_roi`, cap 80 m) on the SGBM disparity
(:func:`msdepth.optimum.sgbm.sgbm_disparity`) as depth, f = 721.5377 px and B = 0.54 m (KITTI's
full-resolution focal and the Monodepth baseline; the frames ship no calibration). The overlay
pictures hold KITTI pixels: write them outside the repository (``--pictures /tmp``)::

    python studies/real_rois.py --out studies/results/real/kitti2015_rois.md --pictures /tmp
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from msdepth.config.params import EvalConfig
from msdepth.data import kitti
from msdepth.data.annotations import gt_density, read_annotation
from msdepth.errors import OutputError, run_main
from msdepth.evaluation.suites import Frame, evaluate_roi
from msdepth.geometry.depth import disparity_to_depth
from msdepth.io import write_png, write_text
from msdepth.optimum.sgbm import sgbm_disparity
from msdepth.outputs import OutputPolicy, output_file_policy

ROIS_CSV = Path("data_lists/kitti2015_rois.csv")
SAMPLES = Path("../shared/real-samples/kitti2015-training")
FOCAL, BASELINE = 721.5377, 0.54
CAP = 80.0
SPARSE = 0.2  # boxes with less GT than this are flagged: their score rests on few pixels
COLOURS = {  # RGB, as the ROI contact sheet's
    "car": (255, 170, 60),
    "windshield": (90, 200, 255),
    "glass": (150, 255, 150),
    "sign": (255, 110, 200),
}


def load(samples: Path, names: list[str]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Each frame's left image and GT disparity (px, 0 = none), through the KITTI readers."""
    images = {n: kitti.read_image(samples / "image_2" / f"{n}.png") for n in names}
    gt = {n: kitti.read_disparity(samples / "disp_occ_0" / f"{n}.png") for n in names}
    return images, gt


def sgbm_scores(samples: Path, boxes: pd.DataFrame, gt: dict[str, np.ndarray]) -> dict:
    """The ROI suite's summary at cap 80 m for SGBM's depth of every frame of ``boxes``."""
    frames, pred = [], {}
    for name, disp in gt.items():
        left = kitti.read_image(samples / "image_2" / f"{name}.png")
        right = kitti.read_image(samples / "image_3" / f"{name}.png")
        pred[name] = disparity_to_depth(sgbm_disparity(left, right)[0], FOCAL, BASELINE)
        frames.append(Frame.from_disparity(name, disp, FOCAL, BASELINE))
    summary, _ = evaluate_roi(pred, frames, boxes, EvalConfig(caps=(CAP,)))
    return summary


def overlay(image: np.ndarray, boxes: pd.DataFrame, density: np.ndarray, scale: int = 2) -> np.ndarray:
    """``image`` (RGB) enlarged ``scale`` times and brightened, each box drawn in its class colour
    and labelled with its row number and GT density."""
    bright = (255 * (image / 255.0) ** 0.6).astype(np.uint8)  # KITTI's shadows hide dark cars
    big = cv2.resize(bright, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC)
    for k, box in zip(boxes.index, boxes.itertuples(index=False), strict=True):
        colour = COLOURS[box[1]]
        top_left, bottom_right = (box.x0 * scale, box.y0 * scale), (box.x1 * scale - 1, box.y1 * scale - 1)
        cv2.rectangle(big, top_left, bottom_right, colour, 2)
        label = f"{k + 2} {box[1]} {density[k]:.0%}"  # the CSV line number names the box
        cv2.putText(big, label, (top_left[0] + 2, top_left[1] + 12), cv2.FONT_HERSHEY_SIMPLEX, 0.4, colour, 1)
    return big


def density_table(boxes: pd.DataFrame, density: np.ndarray) -> list[str]:
    """One markdown row per box: CSV line, frame, class, box, size, GT density, a flag if sparse."""
    lines = [
        "| line | frame | class | x0, y0, x1, y1 | size (px) | GT density | |",
        "|---|---|---|---|---|---|---|",
    ]
    for k, box in zip(boxes.index, boxes.itertuples(index=False), strict=True):
        flag = f"< {SPARSE * 100:g} %" if density[k] < SPARSE else ""
        lines.append(
            f"| {k + 2} | {box.image} | {box[1]} | {box.x0}, {box.y0}, {box.x1}, {box.y1} | "
            f"{box.x1 - box.x0}x{box.y1 - box.y0} | {density[k]:.3f} | {flag} |"
        )
    return lines


def score_table(summary: dict) -> list[str]:
    """The ROI suite's abs_rel per class (and over all boxes), with the boxes it scored."""
    at = summary[f"cap{CAP:g}"]
    lines = ["| class | boxes scored | abs_rel | a1 |", "|---|---|---|---|"]
    for cls, m in sorted(at["by_class"].items()):
        lines.append(f"| {cls} | {m['count']} | {m['abs_rel']:.3f} | {m['a1']:.3f} |")
    o = at["overall"]
    lines.append(f"| all | {o['count']} | {o['abs_rel']:.3f} | {o['a1']:.3f} |")
    return lines


def report(rois_csv: Path, samples: Path, pictures: Path | None) -> str:
    """The study's markdown; the overlay pictures go to ``pictures`` when given."""
    boxes = read_annotation(rois_csv)
    names = sorted(boxes["image"].unique())
    images, gt = load(samples, names)
    density = gt_density(boxes, gt)
    if pictures is not None:
        for name in names:
            rows = boxes["image"] == name
            picture = overlay(images[name], boxes[rows], density)
            write_png(pictures / f"rois_{name.split('_')[0]}.png", picture)
    summary = sgbm_scores(samples, boxes, gt)
    counts = boxes["class"].value_counts()
    head = [
        f"Generated by `studies/real_rois.py` from `{rois_csv.as_posix()}` ({len(boxes)} boxes: "
        + ", ".join(f"{c} {counts.get(c, 0)}" for c in kitti.ROI_CLASSES)
        + ") and the KITTI 2015 frames of `../shared/real-samples/` (`disp_occ_0` GT).",
        "",
        f"## GT density per box (flagged: under {SPARSE * 100:g} %)",
        "",
    ]
    scores = [
        "",
        f"## SGBM inside the boxes (ROI suite, cap {CAP:g} m; f = {FOCAL} px, B = {BASELINE} m)",
        "",
        f"Boxes without GT are left out by the suite: {summary['excluded_rois']} of {summary['rois']}.",
        "",
    ]
    return "\n".join(head + density_table(boxes, density) + scores + score_table(summary)) + "\n"


def claim_outputs(out: Path | None, pictures: Path | None, rois_csv: Path, samples: Path) -> None:
    """Claim the report and each frame's overlay picture (:class:`msdepth.outputs.OutputPolicy`) before
    any work; an OutputError names a file the study did not write."""
    if out is not None:
        output_file_policy(out, "real-rois").claim([out], samples)
    if pictures is not None:
        names = sorted(read_annotation(rois_csv)["image"].unique())
        paths = [pictures / f"rois_{name.split('_')[0]}.png" for name in names]
        OutputPolicy(pictures, "real-rois").claim(paths, samples)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rois", type=Path, default=ROIS_CSV)
    ap.add_argument("--samples", type=Path, default=SAMPLES)
    ap.add_argument("--out", type=Path, help="the markdown report (printed if not given)")
    ap.add_argument("--pictures", type=Path, help="folder for rois_<frame>.png (KITTI pixels: not the repo)")
    args = ap.parse_args(argv)
    try:  # the claims first: a user's file at an output name is refused, not replaced
        claim_outputs(args.out, args.pictures, args.rois, args.samples)
    except OutputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    text = report(args.rois, args.samples, args.pictures)
    if args.out:
        write_text(args.out, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/real_rois.py", main))
