"""One full training step (model + loss + backward + Adam) with SSIM vs each MS-SSIM kernel size.

    python benchmarks/train_step.py                               # params.yaml's model and size
    python benchmarks/train_step.py --device cuda --width-multiplier 1 --height 256 --width 512

Same model weights, same batch, candidates interleaved; prints time per step and the ratio to
the SSIM step (the issue's target: MS-SSIM / SSIM <= 1.10 for every kernel size).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import torch

from _timing import compare, device_from, table
from msdepth.config import load_params
from msdepth.losses import MonodepthLoss
from msdepth.model import MonodepthVGG


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--params", default=str(Path(__file__).resolve().parents[1] / "params.yaml"))
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--batch", type=int, default=None, help="default: train.batch_size")
    ap.add_argument("--height", type=int, default=None, help="default: data.height")
    ap.add_argument("--width", type=int, default=None, help="default: data.width")
    ap.add_argument("--width-multiplier", type=float, default=None, help="default: model.width_multiplier")
    ap.add_argument("--kernels", default="3,5,7,11")
    ap.add_argument("--repeats", type=int, default=15)
    args = ap.parse_args()
    params = load_params(args.params)
    device = device_from(args.device)
    torch.set_num_threads(params.train.threads)
    batch = args.batch or params.train.batch_size
    h, w = args.height or params.data.height, args.width or params.data.width
    model = MonodepthVGG(args.width_multiplier or params.model.width_multiplier,
                         init_disparity=params.model.init_disparity).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-6)  # tiny: weights barely move between repeats
    gen = torch.Generator().manual_seed(0)
    left = torch.rand(batch, 3, h, w, generator=gen).to(device)
    right = torch.roll(left, shifts=-3, dims=-1)

    def step_with(criterion: MonodepthLoss):
        def step():
            losses = criterion(model(left), left, right)
            optimizer.zero_grad(set_to_none=True)
            losses["total"].backward()
            optimizer.step()
        return step

    candidates = {"SSIM k3": step_with(MonodepthLoss(params.loss, "ssim", params.ssim, params.msssim))}
    for k in (int(s) for s in args.kernels.split(",")):
        cfg = dataclasses.replace(params.msssim, kernel_size=k)
        candidates[f"MS-SSIM k{k}"] = step_with(MonodepthLoss(params.loss, "msssim", params.ssim, cfg))
    medians = compare(candidates, device, repeats=args.repeats)
    print(f"training step, batch {batch}x3x{h}x{w}, model x{model_width(args, params)}, {device}, "
          f"{torch.get_num_threads()} threads, median of {args.repeats}\n")
    print(table(medians, "SSIM k3"))
    print(f"\nimages/s: " + ", ".join(f"{n} {batch / t:.1f}" for n, t in medians.items()), file=sys.stdout)


def model_width(args, params) -> float:
    return args.width_multiplier or params.model.width_multiplier


if __name__ == "__main__":
    main()
