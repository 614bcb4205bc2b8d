"""Seconds per stereo pair of the losses' own optimum (msdepth.optimum.solver), variants side by side.

    python benchmarks/optimum.py                       # 125 x 414 and 375 x 1242, params.yaml's optimum
    python benchmarks/optimum.py --sizes 125x414 --iterations 50 --batch 4 --repeats 5

Candidates: SSIM (the baseline of the ratios), MS-SSIM k = 3 and k = 11, each the full optimum
(every coarse-to-fine level, ``optimum.iterations`` Adam steps per level) of a batch of rendered
pairs (random textures: the time does not depend on the content), timed interleaved by
``_timing.compare``. One warm-up call each (the first Adam imports torch's compiler machinery).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import torch
from _timing import compare, table

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from msdepth.config.params import load_params  # noqa: E402
from msdepth.optimum.solver import objective, optimise  # noqa: E402

CANDIDATES = {"SSIM k3": ("ssim", 3), "MS-SSIM k3": ("msssim", 3), "MS-SSIM k11": ("msssim", 11)}


def size(text: str) -> tuple[int, int]:
    height, _, width = text.partition("x")
    return int(height), int(width)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", nargs="+", type=size, default=[(125, 414), (375, 1242)], metavar="HxW")
    ap.add_argument("--iterations", type=int, help="Adam steps per level (default: params.yaml's)")
    ap.add_argument("--batch", type=int, default=1, help="pairs per optimum call")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=torch.get_num_threads())
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    params = load_params(ROOT / "params.yaml")
    cfg = params.optimum
    if args.iterations:
        cfg = dataclasses.replace(cfg, iterations=args.iterations)
    print(
        f"optimum: {cfg.levels} levels x {cfg.iterations} steps, batch {args.batch}, {args.threads} thread(s)"
    )
    gen = torch.Generator().manual_seed(0)
    for height, width in args.sizes:
        left = torch.rand(args.batch, 3, height, width, generator=gen)
        right = torch.roll(left, 4, dims=-1)
        candidates = {}
        for name, (variant, kernel) in CANDIDATES.items():
            section = dataclasses.replace(params.appearance[variant], kernel_size=kernel)
            p = dataclasses.replace(params, appearance={**params.appearance, variant: section})
            criterion = objective(p, variant)
            candidates[name] = lambda c=criterion, lt=left, rt=right: optimise(lt, rt, c, cfg)
        timings = compare(candidates, torch.device("cpu"), repeats=args.repeats, warmup=1)
        print(f"\n{height} x {width}: seconds per pair")
        print(table(timings, "SSIM k3", unit_scale=1.0 / args.batch, unit="s per pair"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
