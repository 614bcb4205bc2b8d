"""One full training step of each train.mode: stereo (Monodepth) vs mono and mono_stereo (Monodepth2's M, MS).

    python benchmarks/mode_step.py                                  # params.yaml's sizes and variant ssim
    python benchmarks/mode_step.py --pose-widths 0.25,1             # the pose network at each width
    python benchmarks/mode_step.py --device cuda --width-multiplier 1 --height 192 --width 640 --batch 12

Same depth network, same random batch, candidates interleaved (benchmarks/_timing.py); prints the
time per step and its ratio to the stereo step. A monocular step runs the depth network on the
target, the pose network on each (target, source) pair and the reprojection loss over the
sources (:func:`msdepth.losses.monocular.monocular_losses`, as training calls it), then backward and Adam.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import Callable

import torch
from _timing import compare, device_from, table

from msdepth.config.params import Params, load_params
from msdepth.losses.monocular import build_monocular_loss, monocular_losses
from msdepth.losses.objective import build_loss
from msdepth.networks.common import MAX_DISPARITY
from msdepth.training.train import build_model, build_pose_net, forward_and_loss


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--params", default=str(Path(__file__).resolve().parents[1] / "params.yaml"))
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--variant", default="ssim")
    ap.add_argument("--batch", type=int, default=None, help="default: train.batch_size")
    ap.add_argument("--height", type=int, default=None, help="default: data.height")
    ap.add_argument("--width", type=int, default=None, help="default: data.width")
    ap.add_argument("--width-multiplier", type=float, default=None, help="default: model.width_multiplier")
    ap.add_argument("--pose-widths", default=None, help="default: model.pose_width_multiplier")
    ap.add_argument("--repeats", type=int, default=10)
    return ap


def _params(args: argparse.Namespace) -> Params:
    params = load_params(args.params)
    data = dataclasses.replace(
        params.data, height=args.height or params.data.height, width=args.width or params.data.width
    )
    model = dataclasses.replace(
        params.model, width_multiplier=args.width_multiplier or params.model.width_multiplier
    )
    train = dataclasses.replace(params.train, batch_size=args.batch or params.train.batch_size)
    return dataclasses.replace(params, data=data, model=model, train=train)


def stereo_step(params: Params, variant: str, device: torch.device, batch: dict) -> Callable[[], None]:
    """The stereo training step (msdepth.training.train.forward_and_loss)."""
    model, criterion = build_model(params).to(device), build_loss(params, variant).to(device)
    optimizer = torch.optim.Adam([*model.parameters(), *criterion.parameters()], lr=1e-6)

    def step() -> None:
        losses = forward_and_loss(
            model, criterion, batch["target"], batch["partner"], "none", torch.contiguous_format
        )
        optimizer.zero_grad(set_to_none=True)
        losses["total"].backward()
        optimizer.step()

    return step


def mono_step(
    params: Params, variant: str, device: torch.device, batch: dict, pose_width: float, stereo: bool
) -> Callable[[], None]:
    """A mono (``stereo`` False) or mono_stereo training step with the pose network at ``pose_width``."""
    params = dataclasses.replace(
        params, model=dataclasses.replace(params.model, pose_width_multiplier=pose_width)
    )
    model, criterion = build_model(params).to(device), build_monocular_loss(params, variant).to(device)
    pose_net = build_pose_net(params).to(device)
    optimizer = torch.optim.Adam(
        [*model.parameters(), *criterion.parameters(), *pose_net.parameters()], lr=1e-6
    )

    def depth(image: torch.Tensor) -> list[torch.Tensor]:
        return [d[:, :1] / MAX_DISPARITY for d in model(image)]  # as training reads the left channel

    def step() -> None:
        partner = batch["partner"] if stereo else None
        losses = monocular_losses(
            depth, pose_net, criterion, batch["target"], batch["neighbours"], batch["k"], partner
        )
        optimizer.zero_grad(set_to_none=True)
        losses["total"].backward()
        optimizer.step()

    return step


def random_batch(params: Params, device: torch.device) -> dict:
    """A target, its frames -1 and +1 (shifted copies), its stereo partner and KITTI-like intrinsics."""
    b, h, w = params.train.batch_size, params.data.height, params.data.width
    target = torch.rand(b, 3, h, w, generator=torch.Generator().manual_seed(0)).to(device)
    k = torch.eye(4).repeat(b, 1, 1)
    k[:, 0, 0], k[:, 1, 1], k[:, 0, 2], k[:, 1, 2] = 0.58 * w, 1.92 * h, 0.5 * w, 0.5 * h  # Monodepth2's
    return {
        "target": target,
        "partner": torch.roll(target, -3, -1),
        "neighbours": {-1: torch.roll(target, 2, -2), 1: torch.roll(target, -2, -2)},
        "k": k.to(device),
    }


def main() -> None:
    args = _parser().parse_args()
    params, device = _params(args), device_from(args.device)
    torch.set_num_threads(params.train.threads)
    batch = random_batch(params, device)
    widths = [float(x) for x in (args.pose_widths or str(params.model.pose_width_multiplier)).split(",")]
    candidates = {"stereo": stereo_step(params, args.variant, device, batch)}
    for width in widths:
        candidates[f"mono (pose x{width:g})"] = mono_step(params, args.variant, device, batch, width, False)
        candidates[f"mono_stereo (pose x{width:g})"] = mono_step(
            params, args.variant, device, batch, width, True
        )
    p = params
    print(
        f"{args.variant}, batch {p.train.batch_size} at {p.data.height}x{p.data.width}, depth network "
        f"x{p.model.width_multiplier:g}, {device}, {p.train.threads} thread(s), {args.repeats} rounds"
    )
    timings = compare(candidates, device, repeats=args.repeats)
    print(table(timings, "stereo"))


if __name__ == "__main__":
    main()
