"""Every real stereo pair at hand, scored for every loss variant at every optimum weight (issue #39).

The pairs, from ``../shared/real-samples`` (a pair whose folder is absent is skipped and named):
- ``object``: the KITTI object pair against its Velodyne scan projected into the left camera
  (``studies/score_lidar.py``'s GT; its ``calib.txt``'s focal and baseline; GT in (1e-3, 80) m);
- ``2015 <frame>``: KITTI 2015 training frames against ``disp_occ_0`` (721.5377 px, 0.54 m);
- ``2012 <frame>``: KITTI 2012 training frames against ``disp_occ`` with the reflective surfaces of
  ``disp_refl_occ`` in its place, and the exact class ``reflective`` on its own
  (:mod:`msdepth.data.kitti2012`: its camera, its GT).

Methods per pair: OpenCV's SGBM at full size (:mod:`msdepth.optimum.sgbm`, the reference); per
variant (ssim; msssim with kernel 3 and 7), the cost-volume start (SGM on the variant's own cost
volume, :func:`msdepth.optimum.starts.matched_disparity`) and the variant's optimum at every weight
of ``optimum.smoothness_sweep`` from ``optimum.start`` (:func:`msdepth.optimum.solver.optimum_disparities`),
both at the working size (``--size``, default half) and brought to full size (bilinear on the
disparity as a fraction of the width). Scores at full size on the GT pixels of each class:
abs_rel and a1 of depth (predictions capped at 80 m: a disparity below f·B/80 reads as 80 m;
``metrics.compute_errors``), KITTI's D1 (%) and EPE (px) (``metrics.stereo_errors``); and seconds.
Writes ``<out>/real_pairs.md`` through the output policy::

    OMP_NUM_THREADS=1 python studies/real_pairs.py --out studies/results/real
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from optimum_starts import BASELINE, FOCAL, SAMPLES, variants_of, working_size  # noqa: E402 - sibling study
from score_lidar import lidar_gt  # noqa: E402 - the sibling study's LiDAR GT

from msdepth.data import kitti, kitti2012  # noqa: E402
from msdepth.evaluation.metrics import compute_errors, stereo_errors  # noqa: E402
from msdepth.geometry.depth import clamp_depth, disparity_to_depth  # noqa: E402
from msdepth.io import OutputPolicy, write_text  # noqa: E402
from msdepth.optimum.sgbm import sgbm_disparity  # noqa: E402
from msdepth.optimum.solver import optimum_disparities  # noqa: E402
from msdepth.optimum.starts import matched_disparity  # noqa: E402

CAP, MIN_DEPTH = 80.0, 1e-3
FRAMES = ("000000_10", "000001_10")
REPORT = "real_pairs.md"


@dataclass
class RealPair:
    """One real pair: images (uint8 RGB), GT disparity (px, 0 = none), camera, exact classes."""

    label: str
    gt_name: str
    left: np.ndarray
    right: np.ndarray
    gt_disp: np.ndarray
    focal: float
    baseline: float
    classes: dict[str, np.ndarray] = field(default_factory=dict)  # class -> its pixels (bool)
    gt_in_range: bool = False  # LiDAR GT: only GT in (MIN_DEPTH, CAP), as the Eigen evaluation


def object_pair(base: Path) -> RealPair:
    """The KITTI object pair and its Velodyne scan's disparity in the left camera."""
    left, right = (kitti.read_image(base / f"{side}.png") for side in ("left", "right"))
    focal, baseline = kitti.stereo_from_calib(kitti.read_calib(base / "calib.txt"))
    depth = lidar_gt(base / "lidar.bin", base / "calib.txt", left.shape[:2])
    disp = np.where(depth > 0, focal * baseline / np.maximum(depth, MIN_DEPTH), 0.0).astype(np.float32)
    return RealPair("object", "LiDAR", left, right, disp, focal, baseline, gt_in_range=True)


def kitti2015_pair(base: Path, frame: str) -> RealPair:
    """A KITTI 2015 training frame against ``disp_occ_0`` (no calib: Monodepth's camera)."""
    left, right = (kitti.read_image(base / d / f"{frame}.png") for d in ("image_2", "image_3"))
    gt = kitti.read_disparity(base / "disp_occ_0" / f"{frame}.png")
    return RealPair(f"2015 {frame}", "disp_occ_0", left, right, gt, FOCAL, BASELINE)


def kitti2012_pair(base: Path, frame: str) -> RealPair:
    """A KITTI 2012 training frame against its GT, with its ``reflective`` pixels as a class."""
    paths = kitti2012.frame_paths(base, frame)
    left, right = kitti.read_image(paths["left"]), kitti.read_image(paths["right"])
    gt, reflective = kitti2012.read_gt_disparity(paths["gt"])
    focal, baseline = kitti2012.camera(base, frame, left.shape[1])
    classes = {kitti2012.REFLECTIVE: reflective}
    return RealPair(f"2012 {frame}", "disp_occ+refl", left, right, gt, focal, baseline, classes)


def real_pairs(samples: Path) -> tuple[list[RealPair], list[str]]:
    """Every pair of ``samples`` at hand, and the folders that are absent."""
    pairs, absent = [], []
    readers = {
        "kitti-object-pair": lambda b: [object_pair(b)],
        "kitti2015-training": lambda b: [kitti2015_pair(b, f) for f in FRAMES],
        "kitti2012-training": lambda b: [kitti2012_pair(b, f) for f in kitti2012.frames(b)],
    }
    for folder, read in readers.items():
        if (samples / folder).is_dir():
            pairs += read(samples / folder)
        else:
            absent.append(folder)
    return pairs, absent


def full_size(fraction: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """A disparity (fraction of the width) at a working size as px at the frame's ``shape``."""
    height, width = shape[:2]
    return cv2.resize(fraction, (width, height), interpolation=cv2.INTER_LINEAR) * width


def scores(pair: RealPair, disparity: np.ndarray, mask: np.ndarray) -> dict[str, float] | None:
    """abs_rel and a1 (depth, capped), D1 (%) and EPE (px) on the GT pixels of ``mask``; None if none."""
    gt_depth = disparity_to_depth(pair.gt_disp, pair.focal, pair.baseline)
    mask = mask & (pair.gt_disp > 0)
    if pair.gt_in_range:
        mask &= (gt_depth > MIN_DEPTH) & (gt_depth < CAP)
    if not mask.any():
        return None
    floor = pair.focal * pair.baseline / CAP  # px: a disparity below it is beyond the cap
    pred = disparity_to_depth(np.maximum(disparity, floor), pair.focal, pair.baseline)
    depth = compute_errors(gt_depth[mask], clamp_depth(pred[mask], MIN_DEPTH, CAP))
    stereo = stereo_errors(np.where(mask, pair.gt_disp, 0.0), disparity)
    return {"pixels": int(mask.sum()), "abs_rel": depth["abs_rel"], "a1": depth["a1"],
            "d1": 100 * stereo["d1"], "epe": stereo["epe"]}  # fmt: skip


def methods(pair: RealPair, variants: dict, size: tuple[int, int]):  # noqa: ANN201 - a generator
    """Yield ``(method, full-size disparity in px, seconds)`` for every method on ``pair``."""
    began = time.perf_counter()
    yield "SGBM", sgbm_disparity(pair.left, pair.right)[0], time.perf_counter() - began
    small = [cv2.resize(image, size[::-1], interpolation=cv2.INTER_AREA) for image in (pair.left, pair.right)]
    for label, (name, params) in variants.items():
        began = time.perf_counter()
        start = matched_disparity(*small, params, name, "cost") / size[1]
        yield f"{label} cost start", full_size(start, pair.left.shape), time.perf_counter() - began
        for weight in params.optimum.smoothness_sweep:
            began = time.perf_counter()
            disp = optimum_disparities([(pair.left, pair.right)], params, name, weight, size, progress=False)[
                0
            ]
            seconds = time.perf_counter() - began
            yield f"{label} optimum w{weight:g}", full_size(disp, pair.left.shape), seconds


def score_pairs(pairs: list[RealPair], variants: dict, size_name: str) -> list[dict]:
    """One row per pair, method and class (``all`` and each exact class), printing progress."""
    rows = []
    for number, pair in enumerate(pairs, 1):
        size = working_size(size_name, pair.left.shape)
        for method, disparity, seconds in methods(pair, variants, size):
            masks = {"all": np.ones(pair.gt_disp.shape, bool), **pair.classes}
            for cls, mask in masks.items():
                found = scores(pair, disparity, mask)
                if found is not None:
                    rows.append({"pair": pair.label, "gt": pair.gt_name, "method": method, "class": cls,
                                 "s": seconds, **found})  # fmt: skip
            print(f"[{number}/{len(pairs)}] {pair.label} {method}: {seconds:.1f} s", flush=True)
    return rows


def table(rows: list[dict]) -> list[str]:
    """The markdown table of every row."""
    lines = [
        "| pair | GT | method | class | GT px | abs_rel | a1 | D1 % | EPE px | s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    lines += [
        f"| {r['pair']} | {r['gt']} | {r['method']} | {r['class']} | {r['pixels']} | {r['abs_rel']:.3f} | "
        f"{r['a1']:.3f} | {r['d1']:.1f} | {r['epe']:.2f} | {r['s']:.1f} |"
        for r in rows
    ]
    return lines


def mean_table(rows: list[dict]) -> list[str]:
    """Per class and method, the mean over the pairs that have the class (each pair weighs one)."""
    lines = [
        "| class | method | pairs | abs_rel | a1 | D1 % | EPE px | s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    keys = dict.fromkeys((r["class"], r["method"]) for r in rows)
    for cls, method in sorted(keys, key=lambda k: k[0] != "all"):
        sel = [r for r in rows if r["class"] == cls and r["method"] == method]
        mean = {k: float(np.mean([r[k] for r in sel])) for k in ("abs_rel", "a1", "d1", "epe", "s")}
        lines.append(
            f"| {cls} | {method} | {len(sel)} | {mean['abs_rel']:.3f} | {mean['a1']:.3f} | "
            f"{mean['d1']:.1f} | {mean['epe']:.2f} | {mean['s']:.1f} |"
        )
    return lines


def report(rows: list[dict], pairs: list[RealPair], absent: list[str], size: str, loads: tuple) -> str:
    """The study's markdown: how it was made, the mean table, then every row."""
    shown = ", ".join(f"{p.label} {p.left.shape[1]}x{p.left.shape[0]}" for p in pairs)
    lines = [
        "# Every real pair at hand: SGBM, the cost-volume start and each variant's optimum (issue #39)",
        "",
        f"`OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', '')} python studies/real_pairs.py "
        f"{' '.join(sys.argv[1:])}` (its docstring says what each column is). Pairs: {shown}"
        f"{'; absent: ' + ', '.join(absent) if absent else ''}. Working size: `{size}` of each frame "
        f"(optimum and cost start; SGBM at full size); scored at full size. Torch threads "
        f"{torch.get_num_threads()}; load average {loads[0][0]:.1f} at the start, {loads[1][0]:.1f} at "
        "the end (seconds are indicative). Class `all`: every GT pixel; `reflective`: KITTI 2012's "
        "disp_refl_occ pixels (msdepth.data.kitti2012).",
        "",
        "## Means over the pairs",
        "",
        *mean_table(rows),
        "",
        "## Every pair",
        "",
        *table(rows),
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Score every real pair at hand and write ``<out>/real_pairs.md``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=Path, default=SAMPLES, help="the real-samples folder")
    parser.add_argument("--params", type=Path, default=Path(__file__).resolve().parents[1] / "params.yaml")
    parser.add_argument("--size", default="half", help="working size: full, half, quarter or HxW")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a params override")
    parser.add_argument("--out", type=Path, required=True, help="the folder of real_pairs.md")
    args = parser.parse_args(argv)
    policy = OutputPolicy(args.out, "real-pairs")
    policy.claim([args.out / REPORT], args.samples)
    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "1")))
    variants = variants_of(args.params, args.set)
    pairs, absent = real_pairs(args.samples)
    if not pairs:
        print(f"{args.samples}: no real pair at hand ({', '.join(absent)} absent)", file=sys.stderr)
        return 1
    before = os.getloadavg()
    rows = score_pairs(pairs, variants, args.size)
    text = report(rows, pairs, absent, args.size, (before, os.getloadavg()))
    write_text(args.out / REPORT, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
