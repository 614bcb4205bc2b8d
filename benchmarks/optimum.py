"""Seconds per stereo pair of the losses' own optimum (msdepth.optimum), by start, beside the
previous implementation and OpenCV's SGBM.

    python benchmarks/optimum.py            # 125 x 414 and 375 x 1242, params.yaml's optimum, 2 threads
    python benchmarks/optimum.py --sizes 125x414 --paths cost --variants ssim:3 --repeats 1  # a quick look
    python benchmarks/optimum.py --sizes 125x414 --iterations 10 --batch 4 --repeats 5

Per size, variant (``--variants``, default SSIM k3, MS-SSIM k3 and k11: ``variant:kernel``) and
path (``--paths``), each row the whole call the pipeline makes
(:func:`msdepth.optimum.solver.optimum_disparities` with that ``start``):

- ``constant``: the previous implementation and the baseline of the ratios: from a constant
  disparity, ``optimum.levels`` coarse-to-fine levels x ``optimum.iterations`` Adam steps;
- ``cost`` (the default): the start matched by SGM on the variant's own plane-sweep cost volume
  (D = 0.3·W), then ``optimum.refine_levels`` x ``optimum.refine_iterations`` steps; beside it
  ``cost start``, the start alone (:func:`msdepth.optimum.solver.batch_start`), and the start's
  share of the path (median of the per-round ratio);
- ``cost uncapped``, where the size is wider than ``optimum.max_width``: the cost path with no
  cap (matched and solved at the pair's own size), as it ran before the cap;
- ``sgbm``: OpenCV's SGBM as the start, then the same refinement;
- ``SGBM alone``: OpenCV's matcher (:func:`msdepth.optimum.sgbm.sgbm_disparity`), the anchor: the
  last column is every row's time in SGBM's.

The pairs are rendered evaluation frames (``data.synthetic.seed``, frames 0 .. batch - 1, at each
size): textured street scenes with a real disparity. The cost volume and SGM take the same time
on any content (fixed loops over disparities, rows and paths, no data-dependent branch), and so
does the refinement (a fixed number of steps); SGBM's speckle filter and the hole filling do
depend on it. All candidates of a size are timed interleaved by ``_timing.compare``, one warm-up
call each (the first Adam imports torch's compiler machinery). ``--threads`` sets torch's and
OpenCV's threads (default 2: issue #38's target is ≤ 5 s per 375 x 1242 pair for SSIM and
MS-SSIM k = 3, ≤ 10 s for k = 11, on 2 CPU cores, cost volume and refinement included).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np
import torch
from _timing import Timings, compare, table

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from msdepth.config.params import Params, load_params  # noqa: E402
from msdepth.optimum.sgbm import sgbm_disparity  # noqa: E402
from msdepth.optimum.solver import batch_start, optimum_disparities  # noqa: E402
from msdepth.optimum.starts import capped_size  # noqa: E402
from msdepth.render import EVAL, Frame, render_frame  # noqa: E402

PATHS = ("constant", "cost", "sgbm")
VARIANTS = ("ssim:3", "msssim:3", "msssim:11")
ANCHOR = "SGBM alone"
UNCAPPED = "uncapped"  # the cost path at the pair's own size (optimum.max_width 0), as before the cap
# Issue #38's targets, s per 375 x 1242 pair on 2 CPU cores, the default path (cost).
TARGET_SIZE = (375, 1242)
TARGETS = {"SSIM k3": 5.0, "MS-SSIM k3": 5.0, "MS-SSIM k11": 10.0}
Pairs = list[tuple[np.ndarray, np.ndarray]]


def size(text: str) -> tuple[int, int]:
    """``HxW`` -> (height, width)."""
    height, _, width = text.partition("x")
    return int(height), int(width)


def variant_spec(text: str) -> tuple[str, int]:
    """``variant:kernel`` (e.g. ``msssim:11``) -> (variant, kernel size)."""
    variant, _, kernel = text.partition(":")
    if not kernel.isdigit():
        raise argparse.ArgumentTypeError(f"expected variant:kernel (e.g. msssim:11), got {text!r}")
    return variant, int(kernel)


def label(variant: str, kernel: int) -> str:
    """The rows' name of a variant: ``SSIM k3``, ``MS-SSIM k11``, or ``<variant> k<kernel>``."""
    names = {"ssim": "SSIM", "msssim": "MS-SSIM"}
    return f"{names.get(variant, variant)} k{kernel}"


def with_kernel(params: Params, variant: str, kernel: int) -> Params:
    """``params`` with ``variant``'s window set to ``kernel`` px."""
    section = dataclasses.replace(params.appearance[variant], kernel_size=kernel)
    return dataclasses.replace(params, appearance={**params.appearance, variant: section})


def uncapped(params: Params) -> Params:
    """``params`` with ``optimum.max_width`` 0: the pair matched and solved at its own size."""
    return dataclasses.replace(params, optimum=dataclasses.replace(params.optimum, max_width=0))


def rendered_frames(params: Params, count: int, height: int, width: int) -> list[Frame]:
    """The first ``count`` rendered evaluation frames (``data.synthetic.seed``) at ``height`` x ``width``."""
    return [render_frame(params.data.synthetic.seed, EVAL, i, height, width) for i in range(count)]


def candidates(
    pairs: Pairs, params: Params, specs: Sequence[tuple[str, int]], paths: Sequence[str]
) -> dict[str, Callable[[], object]]:
    """The timed calls of one size, by row name: per variant each path (and ``cost start`` before
    ``cost``), then :data:`ANCHOR`."""
    shape = pairs[0][0].shape[:2]
    out: dict[str, Callable[[], object]] = {}
    for variant, kernel in specs:
        name, p = label(variant, kernel), with_kernel(params, variant, kernel)
        for path in paths:
            if path == "cost":
                out[f"{name} cost start"] = lambda p=p, v=variant: batch_start(pairs, p, v, "cost", shape)
            out[f"{name} {path}"] = lambda p=p, v=variant, s=path: optimum_disparities(
                pairs, p, v, size=shape, progress=False, start=s
            )
            if path == "cost" and capped_size(shape, p.optimum.max_width) != shape:
                whole = uncapped(p)
                out[f"{name} cost {UNCAPPED}"] = lambda p=whole, v=variant: optimum_disparities(
                    pairs, p, v, size=shape, progress=False, start="cost"
                )
    out[ANCHOR] = lambda: [sgbm_disparity(left, right) for left, right in pairs]
    return out


def report(
    timings: Timings,
    specs: Sequence[tuple[str, int]],
    paths: Sequence[str],
    batch: int,
    shape: tuple[int, int],
) -> str:
    """Per variant, a table of its paths and the anchor (ratios to its first path, the previous
    implementation when ``constant`` is timed), the cost start's share and the target."""
    blocks = []
    for variant, kernel in specs:
        name = label(variant, kernel)
        rows = [row for row in timings.rounds if row.startswith(f"{name} ")] + [ANCHOR]
        subset = Timings({row: timings.rounds[row] for row in rows})
        block = [table(subset, rows[0], unit_scale=1.0 / batch, unit="s per pair", anchor=ANCHOR)]
        if "cost" in paths:
            cost = timings.median(f"{name} cost") / batch
            share = timings.ratio(f"{name} cost start", f"{name} cost")[0]
            line = f"{name}, the default path (cost): {cost:.2f} s per pair, its start {share:.0%} of it"
            if f"{name} cost {UNCAPPED}" in timings.rounds:
                speedup = timings.ratio(f"{name} cost {UNCAPPED}", f"{name} cost")[0]
                line += f", {speedup:.2f}x faster than {UNCAPPED}"
            if shape == TARGET_SIZE and name in TARGETS:
                line += f"; target <= {TARGETS[name]:g} s on 2 cores"
            block.append(line)
        blocks.append("\n".join(block))
    return "\n\n".join(blocks)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The command line (the module docstring's)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", nargs="+", type=size, default=[(125, 414), TARGET_SIZE], metavar="HxW")
    ap.add_argument("--paths", nargs="+", choices=PATHS, default=list(PATHS), help="starts to time")
    ap.add_argument(
        "--variants",
        nargs="+",
        type=variant_spec,
        default=[variant_spec(v) for v in VARIANTS],
        metavar="VARIANT:KERNEL",
        help=f"default: {' '.join(VARIANTS)}",
    )
    ap.add_argument(
        "--iterations", type=int, help="Adam steps per level, every path (default: params.yaml's)"
    )
    ap.add_argument(
        "--refine-iterations", type=int, help="the matched starts' steps per level (default: --iterations)"
    )
    ap.add_argument("--batch", type=int, default=1, help="pairs per optimum call")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--warmup", type=int, default=1, help="untimed calls per candidate and size")
    ap.add_argument("--threads", type=int, default=2, help="torch and OpenCV threads (the target's 2 cores)")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Time every size's candidates and print their tables."""
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)
    params = load_params(ROOT / "params.yaml")
    cfg = dataclasses.replace(params.optimum, batch_size=args.batch)
    refine = args.refine_iterations or args.iterations
    if args.iterations:
        cfg = dataclasses.replace(cfg, iterations=args.iterations)
    if refine:
        cfg = dataclasses.replace(cfg, refine_iterations=refine)
    params = dataclasses.replace(params, optimum=cfg)
    print(
        f"optimum: constant start {cfg.levels} levels x {cfg.iterations} steps, matched starts "
        f"{cfg.refine_levels} levels x {cfg.refine_iterations} steps; batch {args.batch}, "
        f"{args.threads} thread(s); rendered evaluation frames (seed {params.data.synthetic.seed})"
    )
    for height, width in args.sizes:
        frames = rendered_frames(params, args.batch, height, width)
        pairs = [(frame.left, frame.right) for frame in frames]
        calls = candidates(pairs, params, args.variants, args.paths)
        timings = compare(calls, torch.device("cpu"), repeats=args.repeats, warmup=args.warmup)
        largest = max(float(frame.disp.max()) for frame in frames)
        print(f"\n{height} x {width}: seconds per pair (true disparities up to {largest:.0f} px)")
        print(report(timings, args.variants, args.paths, args.batch, (height, width)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
