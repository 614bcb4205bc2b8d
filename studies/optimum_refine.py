"""Refinement of the losses' own optimum from a matched start (issue #38), on real KITTI 2015 frames
of ../shared/real-samples (training 000000_10 and 000001_10, GT ``disp_occ_0``; f = 721.5377 px,
B = 0.54 m, depth capped at 80 m, as studies/optimum_starts.py scores).

``steps``: per frame, variant, start and refinement learning rate, at one working size, the
finest level's loss and the full-size abs_rel / D1 after 0, 10, 25, 50, 100 and 200 Adam steps
(one run of 200 steps, scored at those steps): the measurement behind ``optimum.refine_iterations``
and ``optimum.learning_rate`` (the one both paths use).

``sizes``: per frame, variant and start, the optimum at full, half and quarter working size (the
params' refinement settings; the constant start runs the coarse-to-fine solver), each brought to
full size (bilinear on the disparity as a fraction of width) and scored there, plus seconds. The
start is matched once, at the frame's own size (:mod:`msdepth.optimum.starts`), so every size
refines the same map. The smoothness weight is the solver's ``working_weight``: scaled with the
working width by ``--set optimum.smoothness_width=N``. Prints markdown::

    python studies/optimum_refine.py steps --size 188x621 --out studies/results/optimum/refine_steps.md
    python studies/optimum_refine.py sizes --out studies/results/optimum/sizes.md
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from msdepth.config.params import Params, apply_overrides, kernel_variant, params_from_dict, read_params_file
from msdepth.data.kitti import read_disparity, read_image
from msdepth.data.pairs import resize, to_tensor
from msdepth.errors import run_main
from msdepth.io import write_text
from msdepth.optimum.solver import disparity_pyramid, level_sizes, objective, optimise, working_weight
from msdepth.optimum.starts import start_disparity
from msdepth.outputs import claim_output_file
from msdepth.studies.real_samples import Result, samples_dir, scores, working_size

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = samples_dir(ROOT)
FRAMES = ("000000_10", "000001_10")
VARIANTS = ("ssim", "msssim:3", "msssim:7")
STARTS = ("constant", "cost", "sgbm")
MARKS = (0, 10, 25, 50, 100, 200)  # steps scored by ``steps``


def variant_params(base: Path, spec: str, overrides: list[str]) -> tuple[str, Params]:
    """``(variant, params)`` of a studies spec (``msssim:7``: its kernel size) on ``base``, overridden."""
    raw = apply_overrides(read_params_file(base), overrides)
    name, raw = kernel_variant(raw, spec)
    return name, params_from_dict(raw)


def kitti_frame(samples: Path, frame: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A KITTI 2015 training frame: left, right (uint8 RGB) and the left GT disparity (px)."""
    base = samples / "kitti2015-training"
    left, right = (read_image(base / d / f"{frame}.png") for d in ("image_2", "image_3"))
    return left, right, read_disparity(base / "disp_occ_0" / f"{frame}.png")


def full_size_scores(disp: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """abs_rel, D1 (%), EPE of a left disparity (fraction of width, any size) brought to GT's size."""
    height, width = gt.shape
    if disp.shape != gt.shape:
        disp = cv2.resize(disp, (width, height), interpolation=cv2.INTER_LINEAR)
    return scores(gt, Result("", disp * width, np.ones(gt.shape, dtype=bool), 0.0))


def row(*cells: object) -> str:
    """A markdown table row."""
    return "| " + " | ".join(str(c) for c in cells) + " |"


def scored(s: dict[str, float]) -> tuple[str, str, str]:
    """abs_rel, D1 and EPE cells."""
    return f"{s['abs_rel']:.3f}", f"{s['d1']:.1f}", f"{s['epe']:.2f}"


def refine_trace(pair, gt, params: Params, variant: str, start: np.ndarray, size, levels: int) -> list[dict]:
    """One refinement from ``start`` (2, H, W at ``size``) at the finest ``levels`` levels, of
    :data:`MARKS`[-1] + 1 steps each: per mark of the finest level, its loss and full-size scores
    (step 0: the level's start, the coarser level's result or ``start``)."""
    steps = MARKS[-1] + 1  # trace[k]: the loss after k steps (before step k + 1)
    cfg = dataclasses.replace(params.optimum, refine_levels=levels, refine_iterations=steps)
    left, right = (to_tensor(resize(x, *size))[None] for x in pair)
    marks: dict[int, np.ndarray] = {0: start[0]}
    calls = [0]

    def observe(step: int, disp: torch.Tensor) -> None:
        calls[0] += 1
        finest = calls[0] > steps * (len(level_sizes(*size, levels)) - 1)
        if (finest and step in MARKS) or (not finest and step == steps):
            marks[step if finest else 0] = disp[0, 0].numpy().copy()

    trace: list[list[float]] = []
    optimise(left, right, objective(params, variant), cfg, trace, torch.from_numpy(start)[None], observe)
    return [{**full_size_scores(marks[m], gt), "step": m, "loss": trace[-1][m]} for m in MARKS]


def steps_study(args: argparse.Namespace) -> list[str]:
    """The ``steps`` table's lines."""
    lines = [row("frame", "variant", "start", "levels", "lr", "step", "loss", "abs_rel", "D1 %")]
    lines.append(row(*["---"] * 9))
    for frame in args.frames:
        left, right, gt = kitti_frame(args.samples, frame)
        size = working_size(args.size, gt.shape)
        for spec in args.variants:
            variant, params = variant_params(args.params, spec, args.set)
            for start in [s for s in args.starts if s != "constant"]:
                init = start_disparity(left, right, params, variant, start, size)
                for levels, rate in itertools.product(args.levels, args.rates):
                    run = dataclasses.replace(
                        params, optimum=dataclasses.replace(params.optimum, learning_rate=rate)
                    )
                    for r in refine_trace((left, right), gt, run, variant, init, size, levels):
                        cells = (frame, spec, start, levels, f"{rate:g}", r["step"], f"{r['loss']:.5f}")
                        lines.append(row(*cells, f"{r['abs_rel']:.3f}", f"{r['d1']:.1f}"))
                    print(lines[-1], flush=True)
    return lines


def optimum_at(
    pair, params: Params, variant: str, init: np.ndarray | None, size, weight: float
) -> tuple[np.ndarray, float]:
    """The left optimum (fraction of width) at working ``size`` from ``init`` (the full-size start,
    resampled here) or, for None, the constant start; and the objective's value there."""
    left, right = (to_tensor(resize(x, *size))[None] for x in pair)
    start = None
    if init is not None:
        resampled = cv2.resize(init.transpose(1, 2, 0), size[::-1], interpolation=cv2.INTER_AREA)
        start = torch.from_numpy(resampled).permute(2, 0, 1)[None].contiguous()
    criterion = objective(params, variant, weight)
    disp = optimise(left, right, criterion, params.optimum, start=start)
    with torch.no_grad():
        loss = float(criterion(disparity_pyramid(disp), left, right)["total"])
    return disp[0, 0].numpy(), loss


def sizes_study(args: argparse.Namespace) -> list[str]:
    """The ``sizes`` table's lines."""
    lines = [row("frame", "variant", "start", "size", "weight", "loss", "abs_rel", "D1 %", "EPE px", "s")]
    lines.append(row(*["---"] * 10))
    for frame in args.frames:
        left, right, gt = kitti_frame(args.samples, frame)
        for spec in args.variants:
            variant, params = variant_params(args.params, spec, args.set)
            for start in args.starts:
                began = time.perf_counter()
                init = None if start == "constant" else start_disparity(left, right, params, variant, start)
                if init is not None:
                    seconds = f"{time.perf_counter() - began:.1f}"
                    cells = (frame, spec, f"{start} (start)", "full", "", "")
                    lines.append(row(*cells, *scored(full_size_scores(init[0], gt)), seconds))
                for name in args.sizes:
                    size = working_size(name, gt.shape)
                    weight = working_weight(params, size[1])
                    began = time.perf_counter()
                    disp, loss = optimum_at((left, right), params, variant, init, size, weight)
                    seconds = f"{time.perf_counter() - began:.1f}"
                    cells = (
                        frame,
                        spec,
                        start,
                        f"{name} {size[0]}x{size[1]}",
                        f"{weight:.3g}",
                        f"{loss:.5f}",
                    )
                    lines.append(row(*cells, *scored(full_size_scores(disp, gt)), seconds))
                    print(lines[-1], flush=True)
    return lines


def main(argv: list[str] | None = None) -> int:
    """Run the ``steps`` or ``sizes`` study; print its markdown and write it to ``--out``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("study", choices=("steps", "sizes"))
    parser.add_argument("--samples", type=Path, default=SAMPLES, help="the real-samples folder")
    parser.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a params override")
    parser.add_argument("--frames", nargs="+", default=list(FRAMES))
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), help="e.g. ssim msssim:7")
    parser.add_argument("--starts", nargs="+", default=list(STARTS), choices=STARTS)
    parser.add_argument("--size", default="half", help="steps: the working size, HxW or full/half/quarter")
    parser.add_argument("--levels", nargs="+", type=int, default=[1], help="steps: refine_levels values")
    parser.add_argument(
        "--rates", nargs="+", type=float, default=[0.05, 0.02, 0.01], help="steps: learning rates"
    )
    parser.add_argument(
        "--sizes", nargs="+", default=["full", "half", "quarter"], help="sizes: working sizes"
    )
    parser.add_argument("--out", type=Path, help="also write the markdown here")
    args = parser.parse_args(argv)
    if not claim_output_file(args.out, "optimum-refine", args.samples):  # before the work
        return 1
    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "1")))
    load = os.getloadavg()[0]
    lines = steps_study(args) if args.study == "steps" else sizes_study(args)
    shown = " ".join(sys.argv[1:] if argv is None else argv)
    text = (
        "\n".join(
            [
                f"`python studies/optimum_refine.py {shown}` (load average {load:.1f} at the start, "
                f"{os.getloadavg()[0]:.1f} at the end; torch threads {torch.get_num_threads()})",
                "",
                *lines,
            ]
        )
        + "\n"
    )
    print(text)
    if args.out:
        write_text(args.out, text)
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/optimum_refine.py", main))
