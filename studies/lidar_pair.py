"""The KITTI object pair against its Velodyne scan: the one real pair at hand that no evaluation set holds.

KITTI 2012 and 2015 frames go through the pipeline itself (``eval.extra_sets``: every instrument,
the optimum's sweep with ``optimum.set_weights``, the frames' exact classes and the boxes of
``data/index/set_rois/``; the run on the shared samples: ``studies/results/real_sets``). The object
benchmark's pair (``../shared/real-samples/kitti-object-pair``: ``left.png``, ``right.png``,
``calib.txt``, ``lidar.bin``) is in neither layout: its GT is its scan projected into the left
camera (:func:`msdepth.studies.real_samples.lidar_gt`, as ``studies/score_lidar.py``), scored in
(min_depth, cap) m as the Eigen evaluation scores raw LiDAR.

Methods: OpenCV's SGBM at full size (:mod:`msdepth.optimum.sgbm`); per variant (ssim; msssim with
kernel 3 and 7, :func:`msdepth.studies.real_samples.variants_of`) the cost-volume start (SGM on the
variant's own cost volume) and its optimum at every weight of ``optimum.smoothness_sweep`` (or
``--weights``), at the working size (``--size``, default half) brought to full size (bilinear on the
disparity as a fraction of the width). With ``--models DIR``, every trained network
``DIR/<variant>/seed<S>/model.pt`` of the params' variants, run as ``msdepth predict`` runs a model
file (the left image alone at the file's input size, flip post-processing as ``eval.post_process``).
Scores on the scan's points: abs_rel and a1 of depth (a disparity below f·B/cap reads as the cap),
abs_rel after median scaling (``abs_rel med``), KITTI's D1 (%) and EPE (px), and seconds. One pair
is one unit: no interval, no verdict row. Writes ``<out>/lidar_pair.md`` through the output policy::

    OMP_NUM_THREADS=2 python studies/lidar_pair.py --models models --out studies/results/real
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import dataclass
from itertools import chain
from pathlib import Path
from typing import Iterator, Sequence

import cv2
import numpy as np
import torch

from msdepth.cli.predict import load_trained
from msdepth.config.params import Params
from msdepth.data import kitti
from msdepth.data.pairs import resize, to_tensor
from msdepth.errors import DataError, run_main
from msdepth.evaluation.infer import network_disparity
from msdepth.evaluation.metrics import compute_errors, median_scale, stereo_errors
from msdepth.geometry.depth import clamp_depth, disparity_to_depth
from msdepth.io import write_text
from msdepth.optimum.sgbm import sgbm_disparity
from msdepth.optimum.solver import optimum_disparities
from msdepth.optimum.starts import matched_disparity
from msdepth.outputs import OutputPolicy
from msdepth.studies.real_samples import CAP, MIN_DEPTH, lidar_gt, samples_dir, variants_of, working_size

ROOT = Path(__file__).resolve().parents[1]
PAIR = "kitti-object-pair"  # below the samples folder
REPORT = "lidar_pair.md"
MODEL_FILE = "model.pt"  # --models DIR: DIR/<variant>/seed<S>/model.pt


@dataclass
class LidarPair:
    """The pair: images (uint8 RGB), the scan's disparity in the left camera (px, 0 = none), camera."""

    left: np.ndarray
    right: np.ndarray
    gt_disp: np.ndarray
    focal: float
    baseline: float


def object_pair(base: Path) -> LidarPair:
    """The KITTI object pair of folder ``base`` and its Velodyne scan's disparity in the left camera."""
    for name in ("left.png", "right.png", "calib.txt", "lidar.bin"):
        if not (base / name).is_file():
            raise DataError(f"{base / name}: missing (the KITTI object pair's folder)")
    left, right = (kitti.read_image(base / f"{side}.png") for side in ("left", "right"))
    focal, baseline = kitti.stereo_from_calib(kitti.read_calib(base / "calib.txt"))
    depth = lidar_gt(base / "lidar.bin", base / "calib.txt", left.shape[:2])
    disp = np.where(depth > 0, focal * baseline / np.maximum(depth, MIN_DEPTH), 0.0).astype(np.float32)
    return LidarPair(left, right, disp, focal, baseline)


def full_size(fraction: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """A disparity (fraction of the width) at a working size as px at the frame's ``shape``."""
    height, width = shape[:2]
    return cv2.resize(fraction, (width, height), interpolation=cv2.INTER_LINEAR) * width


def scores(pair: LidarPair, disparity: np.ndarray) -> dict[str, float]:
    """abs_rel and a1 (depth, capped), abs_rel after median scaling (``abs_rel_med``), D1 (%) and EPE
    (px) on the scan's points with depth in (MIN_DEPTH, CAP)."""
    gt_all = disparity_to_depth(pair.gt_disp, pair.focal, pair.baseline)
    mask = (pair.gt_disp > 0) & (gt_all > MIN_DEPTH) & (gt_all < CAP)
    if not mask.any():
        raise DataError("the scan has no point in the evaluated depth range in the left image")
    floor = pair.focal * pair.baseline / CAP  # px: a disparity below it is beyond the cap
    pred = disparity_to_depth(np.maximum(disparity, floor), pair.focal, pair.baseline)[mask]
    gt = gt_all[mask]
    depth = compute_errors(gt, clamp_depth(pred, MIN_DEPTH, CAP))
    scaled = compute_errors(gt, clamp_depth(median_scale(gt, pred)[0], MIN_DEPTH, CAP))
    stereo = stereo_errors(np.where(mask, pair.gt_disp, 0.0), disparity)
    return {"points": int(mask.sum()), "abs_rel": depth["abs_rel"], "abs_rel_med": scaled["abs_rel"],
            "a1": depth["a1"], "d1": 100 * stereo["d1"], "epe": stereo["epe"]}  # fmt: skip


def methods(
    pair: LidarPair, variants: dict[str, tuple[str, Params]], size: tuple[int, int], weights: Sequence[float]
) -> Iterator[tuple[str, np.ndarray, float]]:
    """Yield ``(method, full-size disparity in px, seconds)``: SGBM, then per variant its cost start
    and its optimum at each weight (named as the pipeline names them: ``optimum w10``)."""
    began = time.perf_counter()
    yield "SGBM", sgbm_disparity(pair.left, pair.right)[0], time.perf_counter() - began
    small = [cv2.resize(image, size[::-1], interpolation=cv2.INTER_AREA) for image in (pair.left, pair.right)]
    for label, (name, params) in variants.items():
        began = time.perf_counter()
        start = matched_disparity(*small, params, name, "cost") / size[1]
        yield f"{label} cost start", full_size(start, pair.left.shape), time.perf_counter() - began
        for weight in weights:
            began = time.perf_counter()
            images = [(pair.left, pair.right)]
            disp = optimum_disparities(images, params, name, weight, size, progress=False)[0]
            seconds = time.perf_counter() - began
            yield f"{label} optimum w{weight:g}", full_size(disp, pair.left.shape), seconds


def model_files(models: Path, variants: Sequence[str]) -> dict[str, dict[int, Path]]:
    """Per variant, its model files ``models/<variant>/seed<S>/model.pt`` by seed (sorted); a
    DataError naming the folder where a variant has none."""
    found = {}
    for variant in variants:
        seeds = {}
        for path in (models / variant).glob(f"seed*/{MODEL_FILE}"):
            number = path.parent.name.removeprefix("seed")
            if number.isdigit():
                seeds[int(number)] = path
        if not seeds:
            raise DataError(f"{models / variant}: no seed<S>/{MODEL_FILE} (--models)")
        found[variant] = dict(sorted(seeds.items()))
    return found


def networks(
    pair: LidarPair, files: dict[str, dict[int, Path]], post_process: bool
) -> Iterator[tuple[str, np.ndarray, float]]:
    """Yield ``(network <variant> seed<S>, full-size disparity in px, seconds)`` per model file, each
    loaded through the hardened loader and run as ``msdepth predict`` runs it."""
    for variant, by_seed in files.items():
        for seed, path in by_seed.items():
            model, meta = load_trained(path)
            began = time.perf_counter()
            batch = to_tensor(resize(pair.left, int(meta["height"]), int(meta["width"]))).unsqueeze(0)
            disp = full_size(network_disparity(model, batch, post_process)[0], pair.left.shape)
            yield f"network {variant} seed{seed}", disp, time.perf_counter() - began


def table(rows: list[dict]) -> list[str]:
    """The markdown table: one line per method, then each variant's networks over their seeds."""
    lines = [
        "| method | GT points | abs_rel | abs_rel med | a1 | D1 % | EPE px | s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    groups: dict[str, list[dict]] = {}
    for r in rows:
        if r["method"].startswith("network "):
            groups.setdefault(r["method"].rsplit(" seed", 1)[0], []).append(r)
    keys = ("abs_rel", "abs_rel_med", "a1", "d1", "epe", "s")
    means = [
        {"method": f"{name} (mean of {len(members)} seeds)", "points": members[0]["points"],
         **{k: float(np.mean([m[k] for m in members])) for k in keys}}
        for name, members in groups.items()
    ]  # fmt: skip
    lines += [
        f"| {r['method']} | {r['points']} | {r['abs_rel']:.3f} | {r['abs_rel_med']:.3f} | {r['a1']:.3f} | "
        f"{r['d1']:.1f} | {r['epe']:.2f} | {r['s']:.1f} |"
        for r in [*rows, *means]
    ]
    return lines


def report(rows: list[dict], pair: LidarPair, size: str, words: str) -> str:
    """The study's markdown: how it was made, then the table."""
    shape = f"{pair.left.shape[1]}x{pair.left.shape[0]}"
    command = f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', '')} python studies/lidar_pair.py"
    return "\n".join([
        "# The KITTI object pair against its Velodyne scan",
        "",
        f"`{command} {' '.join(sys.argv[1:])}` (its docstring says what each column is). The pair: "
        f"{shape}, f = {pair.focal:.2f} px, B = {pair.baseline:.4f} m (its calib.txt). Working size "
        f"`{size}` (optimum and cost start; SGBM at full size), scored at full size on the scan's points "
        f"in ({MIN_DEPTH:g}, {CAP:g}) m. Torch threads {torch.get_num_threads()}; seconds are "
        f"indicative.{words}",
        "",
        *table(rows),
    ]) + "\n"  # fmt: skip


def arguments(argv: list[str] | None) -> argparse.Namespace:
    """The command line (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=Path, default=samples_dir(ROOT), help="the real-samples folder")
    parser.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    parser.add_argument("--size", default="half", help="working size: full, half, quarter or HxW")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a params override")
    parser.add_argument(
        "--weights", help="the optimum's weights, e.g. 3,10 (default: optimum.smoothness_sweep)"
    )
    parser.add_argument(
        "--models", type=Path, help="also the trained networks DIR/<variant>/seed<S>/model.pt"
    )
    parser.add_argument("--out", type=Path, required=True, help="the folder of lidar_pair.md")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Score every method on the object pair; write ``<out>/lidar_pair.md``."""
    args = arguments(argv)
    OutputPolicy(args.out, "lidar-pair").claim([args.out / REPORT], args.samples)
    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "1")))
    variants = variants_of(args.params, args.set)
    params = variants["ssim"][1]
    try:
        weights = [float(w) for w in args.weights.split(",")] if args.weights else None
    except ValueError:
        raise DataError(f"--weights {args.weights!r}: expected numbers separated by commas") from None
    weights = weights or list(params.optimum.smoothness_sweep)
    files = model_files(args.models, params.variants) if args.models else {}
    pair = object_pair(args.samples / PAIR)
    size = working_size(args.size, pair.left.shape)
    rows = []
    # Scored as each method finishes: its line is the progress, and one disparity is held at a time.
    found = chain(methods(pair, variants, size, weights), networks(pair, files, params.eval.post_process))
    for method, disparity, seconds in found:
        rows.append({"method": method, "s": seconds, **scores(pair, disparity)})
        print(f"{method}: {seconds:.1f} s", flush=True)
    words = (
        " Networks: trained on the synthetic set, whose camera differs from KITTI's: their metric depth "
        "mostly measures that domain gap, which `abs_rel med` takes the scale out of."
        if files
        else ""
    )
    text = report(rows, pair, args.size, words)
    write_text(args.out / REPORT, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/lidar_pair.py", main))
