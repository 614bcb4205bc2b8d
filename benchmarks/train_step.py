"""One full training step (model + loss + backward + Adam) with SSIM vs each MS-SSIM kernel size.

    python benchmarks/train_step.py                               # params.yaml's model and size
    python benchmarks/train_step.py --device cuda --width-multiplier 1 --height 256 --width 512
    python benchmarks/train_step.py --device cuda ... --amp bf16 --channels-last [--compile]
    python benchmarks/train_step.py --loss-only                   # the loss alone, on the network's output
    python benchmarks/train_step.py --device cuda ... --profile 10  # + GPU busy time and kernels per step
    python benchmarks/train_step.py --networks                    # SSIM step: the dissertation's network vs
                                                                  # GroupNorm / residual heads / both

Same model weights, same batch, candidates interleaved; prints time per step and the ratio to
the SSIM step (the issue's target: MS-SSIM / SSIM <= 1.10 for every kernel size), images/s,
and on CUDA each candidate's peak GPU memory. The step is the training loop's own
(:func:`msdepth.training.train.forward_and_loss`: network in autocast when asked, loss in fp32).
``--profile N`` then runs N more steps of each under the profiler and adds, on CUDA, the GPU's
busy time per step (the sum of its kernels' and copies' durations), that time as a share of
the timed step, and the kernels per step: far below 100 % means the GPU waits for the host,
which queues every kernel from Python.
"""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import torch
from _timing import Timings, compare, device_from, sync, table

from msdepth.config.params import Params, load_params
from msdepth.losses.appearance import build_appearance
from msdepth.losses.monodepth import MonodepthLoss
from msdepth.networks.vgg import MonodepthVGG
from msdepth.training.train import configure_cudnn, forward_and_loss


def _parser() -> argparse.ArgumentParser:
    """The command line: sizes default to params.yaml's, switches to off."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--params", default=str(Path(__file__).resolve().parents[1] / "params.yaml"))
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--batch", type=int, default=None, help="default: train.batch_size")
    ap.add_argument("--height", type=int, default=None, help="default: data.height")
    ap.add_argument("--width", type=int, default=None, help="default: data.width")
    ap.add_argument("--width-multiplier", type=float, default=None, help="default: model.width_multiplier")
    ap.add_argument("--kernels", default="3,5,7,11")
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--amp", choices=["none", "bf16"], default="none", help="network in bf16 autocast")
    ap.add_argument("--channels-last", action="store_true")
    ap.add_argument("--compile", action="store_true", help="torch.compile the network")
    ap.add_argument(
        "--profile",
        type=int,
        default=0,
        metavar="N",
        help="then profile N steps of each candidate: GPU busy time and kernels per step",
    )
    ap.add_argument(
        "--loss-only",
        action="store_true",
        help="time the loss alone (forward+backward) on the network's disparities, computed once",
    )
    ap.add_argument(
        "--networks",
        action="store_true",
        help="instead: the SSIM step with each network option (model.norm x model.heads)",
    )
    return ap


@dataclass(frozen=True)
class Bench:
    """What every candidate shares: the device, the batch, the network and its optimiser."""

    device: torch.device
    batch: int
    h: int
    w: int
    width: float  # the model's width multiplier
    memory_format: torch.memory_format
    model: MonodepthVGG
    forward: Callable  # the model, compiled or not
    optimizer: torch.optim.Optimizer
    left: torch.Tensor
    right: torch.Tensor
    disps: list[torch.Tensor] | None  # the network's output for --loss-only, else None


def setup(args: argparse.Namespace, params: Params) -> Bench:
    """The device configured as training does, the configured network and a random stereo batch."""
    device = device_from(args.device)
    torch.set_num_threads(params.train.threads)
    configure_cudnn(params.train.cudnn_benchmark, device)  # as training does (CUDA only)
    batch = args.batch or params.train.batch_size
    h, w = args.height or params.data.height, args.width or params.data.width
    memory_format = torch.channels_last if args.channels_last else torch.contiguous_format
    m = params.model
    width = args.width_multiplier or m.width_multiplier
    model = MonodepthVGG(width, init_disparity=m.init_disparity, norm=m.norm, heads=m.heads)
    model = model.to(device, memory_format=memory_format)
    forward = torch.compile(model) if args.compile else model
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-6)  # tiny: weights barely move between repeats
    gen = torch.Generator().manual_seed(0)
    left = torch.rand(batch, 3, h, w, generator=gen).to(device)
    right = torch.roll(left, shifts=-3, dims=-1)
    disps = None
    if args.loss_only:  # once, with the plain network: a compiled one would compile a no-grad graph too
        with torch.no_grad():
            disps = [d.float() for d in model(left.contiguous(memory_format=memory_format))]
    return Bench(device, batch, h, w, width, memory_format, model, forward, optimizer, left, right, disps)


def step_with(args: argparse.Namespace, bench: Bench, criterion: MonodepthLoss) -> Callable[[], None]:
    """The timed call: a training step with ``criterion``, or with --loss-only the loss alone."""

    def step():
        losses = forward_and_loss(
            bench.forward, criterion, bench.left, bench.right, args.amp, bench.memory_format
        )
        bench.optimizer.zero_grad(set_to_none=True)
        losses["total"].backward()
        bench.optimizer.step()

    def loss_step():
        # Fresh leaves each call: the loss and its gradient down to the disparities, no network.
        criterion([d.detach().requires_grad_() for d in bench.disps], bench.left, bench.right)[
            "total"
        ].backward()

    return loss_step if args.loss_only else step


def kernel_candidates(
    args: argparse.Namespace, params: Params, bench: Bench, ssim_loss: MonodepthLoss
) -> dict:
    """The SSIM step, then the MS-SSIM step for each of --kernels."""
    candidates = {"SSIM k3": step_with(args, bench, ssim_loss)}
    for k in (int(s) for s in args.kernels.split(",")):
        sections = {**params.appearance, "msssim": dataclasses.replace(params.msssim, kernel_size=k)}
        with_k = dataclasses.replace(params, appearance=sections)
        candidates[f"MS-SSIM k{k}"] = step_with(
            args, bench, MonodepthLoss(params.loss, build_appearance(with_k, "msssim"))
        )
    return candidates


def peak_memory(candidates: dict, device: torch.device) -> dict[str, float]:
    """Each candidate's peak GPU memory (GiB) over one step from a clean peak; none off CUDA."""
    peaks = {}
    if device.type == "cuda":  # one step each from a clean peak, before the timed ones
        for name, step in candidates.items():
            step()
            torch.cuda.synchronize(device)
            torch.cuda.reset_peak_memory_stats(device)
            step()
            torch.cuda.synchronize(device)
            peaks[name] = torch.cuda.max_memory_allocated(device) / 2**30
    return peaks


def report(args: argparse.Namespace, bench: Bench, timings: Timings, peaks: dict[str, float]) -> None:
    """Print the setup line, the time table with ratios to SSIM, images/s and the peak memory."""
    device = bench.device
    switches = f"amp {args.amp}, channels_last {args.channels_last}, compile {args.compile}"
    if device.type == "cuda":
        switches += f", cudnn.benchmark {torch.backends.cudnn.benchmark}"
    what = "loss forward+backward only" if args.loss_only else "training step"
    print(
        f"{what}, batch {bench.batch}x3x{bench.h}x{bench.w}, model x{bench.width}, {device}, "
        f"{torch.get_num_threads()} threads, {switches}, median of {args.repeats}\n"
    )
    print(table(timings, "SSIM k3"))
    print("\nimages/s: " + ", ".join(f"{n} {bench.batch / t:.1f}" for n, t in timings.medians().items()))
    if peaks:
        print("peak GPU memory (GiB): " + ", ".join(f"{n} {g:.2f}" for n, g in peaks.items()))


def main() -> None:
    args = _parser().parse_args()
    params = load_params(args.params)
    bench = setup(args, params)
    ssim_loss = MonodepthLoss(params.loss, build_appearance(params, "ssim"))
    if args.networks:
        run_networks(args, bench, params.model.init_disparity, ssim_loss)
        return
    candidates = kernel_candidates(args, params, bench, ssim_loss)
    peaks = peak_memory(candidates, bench.device)
    timings = compare(candidates, bench.device, repeats=args.repeats)
    report(args, bench, timings, peaks)
    if args.profile:
        print("\n" + profile_table(candidates, timings.medians(), bench.device, args.profile))


def run_networks(args: argparse.Namespace, bench: Bench, init: float, criterion: MonodepthLoss) -> None:
    """The SSIM training step with each (norm, heads) network, interleaved; ratios to the dissertation's."""
    device, memory_format, batch, h, w = bench.device, bench.memory_format, bench.batch, bench.h, bench.w
    candidates = {}
    for norm in ("none", "group"):
        for heads in ("independent", "residual"):
            net = MonodepthVGG(bench.width, init_disparity=init, norm=norm, heads=heads).to(
                device, memory_format=memory_format
            )
            opt = torch.optim.Adam(net.parameters(), lr=1e-6)  # tiny: weights barely move between repeats
            gen = torch.Generator().manual_seed(0)
            left = torch.rand(batch, 3, h, w, generator=gen).to(device)
            right = torch.roll(left, shifts=-3, dims=-1)

            def step(net=net, opt=opt, left=left, right=right):
                losses = forward_and_loss(net, criterion, left, right, args.amp, memory_format)
                opt.zero_grad(set_to_none=True)
                losses["total"].backward()
                opt.step()

            candidates[f"norm {norm}, heads {heads}"] = step
    timings = compare(candidates, device, repeats=args.repeats)
    print(
        f"SSIM training step by network, batch {batch}x3x{h}x{w}, model x{bench.width}, {device}, "
        f"{torch.get_num_threads()} threads, median of {args.repeats}\n"
    )
    print(table(timings, "norm none, heads independent"))


def profile_table(candidates: dict, step_seconds: dict[str, float], device: torch.device, steps: int) -> str:
    """Per candidate: the GPU's busy time per step (kernels and copies, from the profiler), as a
    share of the timed step, and the device operations per step. Without a GPU there is nothing
    to measure: the table then lists the step times with empty GPU columns, profiling nothing."""
    from torch.autograd import DeviceType
    from torch.profiler import ProfilerActivity, profile

    rows = [
        "| candidate | step ms | GPU busy ms/step | GPU busy share | GPU ops/step |",
        "|---|---|---|---|---|",
    ]
    for name, step in candidates.items():
        step_ms = step_seconds[name] * 1e3
        if device.type != "cuda":
            rows.append(f"| {name} | {step_ms:.2f} | - | - | - |")
            continue
        sync(device)
        with profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA]) as prof:
            for _ in range(steps):
                step()
            sync(device)
        ops = [e for e in prof.events() if e.device_type == DeviceType.CUDA]
        if not ops:  # not a 0 % that would read as an idle GPU
            rows.append(f"| {name} | {step_ms:.2f} | no GPU operations recorded by the profiler | - | - |")
            continue
        busy_ms = sum(e.device_time_total for e in ops) / 1e3 / steps
        rows.append(
            f"| {name} | {step_ms:.2f} | {busy_ms:.2f} | {busy_ms / step_ms:.0%} | {len(ops) / steps:.0f} |"
        )
    return "\n".join(rows)


if __name__ == "__main__":
    main()
