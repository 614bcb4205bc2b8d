"""Forward+backward time of appearance losses, side by side in one process.

    python benchmarks/loss.py                      # CPU: batch 2 x 3 x 256 x 512
    python benchmarks/loss.py --device cuda --batch 8

Candidates (each ``alpha*(1-S)/2 + (1-alpha)*L1`` with alpha = 0.85, so only S differs):
ours SSIM (3x3 box, the baseline), ours MS-SSIM (4 levels, box k=3, the training setting),
ours MS-SSIM in pytorch-msssim's configuration (gaussian 11, sigma 1.5, 5 levels, valid) and
pytorch-msssim's ``ms_ssim`` itself, and torchmetrics' MS-SSIM when it is installed. The last
two columns of the issue's target compare the like-for-like pair.

Measurements behind the design of ``msdepth.losses.ssim_kernels`` (2 CPU threads):

- Window sums. Box: separable sums of shifted views, built by doubling, beat a separable
  depthwise ``conv2d``, a k x k depthwise ``conv2d`` and ``avg_pool2d`` for every k in 3..11, at
  8x15x64x192 and 2x15x256x512. Gaussian: weighted shifted views were 2.5-3x faster than the
  depthwise ``conv2d`` pair on the chunks ``_SSIMTerms`` filters (k = 11).
- Chunks. On 8x2 images of 3x64x192 (forward+backward at level 0), working on 2-4 images at a
  time instead of all 16 made the SSIM map 3x faster: the ~10 passes over the moment maps then
  stay in cache (hence 2^19 elements per chunk on the CPU). On a GPU each chunk costs ~70 kernel
  launches, and at 256x512 the CPU budget would mean one plane per chunk, 48 chunks per call:
  there every plane goes at once (up to 1 GiB).
- ``_Halve``: the 2x2 means of even-sized levels, 3-7x faster than ``avg_pool2d`` on CPU.
- ``ms_ssim_levels``: batching same-sized levels across the 4 scales of the training pyramid
  makes 7 calls instead of 16 for 4 levels, where the coarse ones cost mostly per-call overhead.
"""

from __future__ import annotations

import argparse
import sys

import torch
from _timing import compare, device_from, table

from msdepth.losses.monodepth import appearance_loss
from msdepth.losses.ssim import ms_ssim, ssim

ALPHA = 0.85


def candidates(x: torch.Tensor, y: torch.Tensor) -> dict:
    def run(similarity):
        def step():
            x.grad = None
            appearance_loss(x, y, ALPHA, similarity).backward()

        return step

    out = {
        "ours SSIM k3": run(lambda a, b: ssim(a, b, 3)),
        "ours MS-SSIM box k3 L4": run(lambda a, b: ms_ssim(a, b, 3, 4)),
        "ours MS-SSIM box k7 L4": run(lambda a, b: ms_ssim(a, b, 7, 4)),
        "ours MS-SSIM gauss11 L5": run(
            lambda a, b: ms_ssim(a, b, 11, 5, window="gaussian", sigma=1.5, padding="valid")
        ),
    }
    try:
        from pytorch_msssim import ms_ssim as reference

        out["pytorch-msssim ms_ssim"] = run(lambda a, b: reference(a, b, data_range=1.0, size_average=False))
    except ImportError:
        print("pytorch-msssim not installed: skipped", file=sys.stderr)
    try:
        from torchmetrics.functional.image import multiscale_structural_similarity_index_measure as tm

        out["torchmetrics MS-SSIM"] = run(lambda a, b: tm(a, b, data_range=1.0, reduction="none"))
    except ImportError:
        print("torchmetrics not installed: skipped", file=sys.stderr)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu", help="cpu | cuda | auto")
    ap.add_argument("--batch", type=int, default=None, help="default: 2 on CPU, 8 on CUDA")
    ap.add_argument("--height", type=int, default=256)
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    args = ap.parse_args()
    device = device_from(args.device)
    if args.threads:
        torch.set_num_threads(args.threads)
    batch = args.batch or (8 if device.type == "cuda" else 2)
    gen = torch.Generator().manual_seed(0)
    x = torch.rand(batch, 3, args.height, args.width, generator=gen).to(device).requires_grad_()
    y = (x.detach() + 0.1 * torch.randn(x.shape, generator=gen).to(device)).clamp(0, 1)
    timings = compare(candidates(x, y), device, repeats=args.repeats)
    print(
        f"loss forward+backward, {batch}x3x{args.height}x{args.width}, {device}, "
        f"{torch.get_num_threads()} threads, median of {args.repeats}\n"
    )
    print(table(timings, "ours SSIM k3"))
    if "pytorch-msssim ms_ssim" in timings.rounds:
        print()
        for config, ours in (
            ("same config", "ours MS-SSIM gauss11 L5"),
            ("training config", "ours MS-SSIM box k3 L4"),
        ):
            mid, low, high = timings.ratio("pytorch-msssim ms_ssim", ours)
            print(
                f"pytorch-msssim / ours ({config}, {ours.removeprefix('ours MS-SSIM ')}): "
                f"{mid:.2f}x (IQR {low:.2f}-{high:.2f})"
            )


if __name__ == "__main__":
    main()
