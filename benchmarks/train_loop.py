"""The whole training loop in images/s: loader, augmentation, step, host reads of the loss, checkpoints.

    python benchmarks/train_loop.py                  # params.yaml's model, size and batch, CPU
    python benchmarks/train_loop.py --device cuda --width-multiplier 1 --height 256 --width 512 \\
        --pairs 800 --workers 8 --amp bf16 --channels-last

Each candidate is a complete run of ``msdepth.training.train.train_variant`` (from scratch, ``--epochs``
epochs, its per-epoch checkpoint and final model written to a temporary folder) on ``--pairs``
random stereo pairs held in memory in the pair cache's uint8 layout, so no dataset is needed.
Candidates: each variant with the loss read on the host every step (``train.sync_every: 1``)
and every ``--sync`` steps (what ``sync_every: 0`` picks on a GPU); runs are interleaved. On
the CPU the two should match; on a GPU the difference is what per-step reads cost
(:func:`msdepth.training.train.host_sync_interval`). Wall time includes building the model and the
loader's start-up, so use a few epochs; the step alone is ``train_step.py``.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from _timing import compare, device_from, table

from msdepth.config.params import Params, load_params
from msdepth.training.train import TrainOptions, TrainOutputs, host_sync_interval, train_variant


def size_arguments(ap: argparse.ArgumentParser) -> None:
    """``--params`` and the training sizes, each defaulting to params.yaml's (this benchmark's and
    parallel_trainings.py's)."""
    ap.add_argument("--params", default=str(Path(__file__).resolve().parents[1] / "params.yaml"))
    ap.add_argument("--batch", type=int, default=None, help="default: train.batch_size")
    ap.add_argument("--height", type=int, default=None, help="default: data.height")
    ap.add_argument("--width", type=int, default=None, help="default: data.width")
    ap.add_argument("--width-multiplier", type=float, default=None, help="default: model.width_multiplier")


def _parser() -> argparse.ArgumentParser:
    """The command line: sizes default to params.yaml's."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    size_arguments(ap)
    ap.add_argument("--device", default="cpu", help="cpu | cuda | auto")
    ap.add_argument("--pairs", type=int, default=200)
    ap.add_argument("--epochs", type=int, default=2)
    ap.add_argument("--workers", type=int, default=None, help="default: train.num_workers")
    ap.add_argument("--variants", default="ssim,msssim")
    ap.add_argument(
        "--sync",
        type=int,
        default=host_sync_interval(0, torch.device("cuda")),
        help="the other host-read interval, besides every step (default: what a GPU run uses)",
    )
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--warmup", type=int, default=1, help="untimed runs of each candidate first")
    ap.add_argument("--amp", choices=["none", "bf16"], default="none")
    ap.add_argument("--channels-last", action="store_true")
    return ap


def bench_params(args: argparse.Namespace, base: Params, device: torch.device) -> Params:
    """``base`` with the command line's size, model width and training switches, one seed."""
    h, w = args.height or base.data.height, args.width or base.data.width
    return dataclasses.replace(
        base,
        data=dataclasses.replace(base.data, height=h, width=w),
        model=dataclasses.replace(
            base.model, width_multiplier=args.width_multiplier or base.model.width_multiplier
        ),
        train=dataclasses.replace(
            base.train,
            seeds=(0,),
            epochs=args.epochs,
            batch_size=args.batch or base.train.batch_size,
            num_workers=base.train.num_workers if args.workers is None else args.workers,
            device=device.type,
            amp=args.amp,
            channels_last=args.channels_last,
            compile=False,
            launcher="local",
        ),
    )


def random_pairs(n: int, h: int, w: int) -> tuple[np.ndarray, list[tuple[Path, Path]]]:
    """``n`` random stereo pairs in the pair cache's layout (right = left shifted 3 px), and their names."""
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (n, h, w, 3), dtype=np.uint8)
    cache = np.stack([left, np.roll(left, -3, axis=2)], axis=1)  # (N, 2, H, W, 3), right = left shifted 3 px
    return cache, [(Path(f"pair{i}_left.png"), Path(f"pair{i}_right.png")) for i in range(n)]


def training_run(
    params: Params, variant: str, sync_every: int, pairs: list[tuple[Path, Path]], cache: np.ndarray
) -> Callable[[], None]:
    """A complete training of ``variant``, reading the loss every ``sync_every`` steps, into a temp folder."""
    run_params = dataclasses.replace(params, train=dataclasses.replace(params.train, sync_every=sync_every))

    def train() -> None:
        with tempfile.TemporaryDirectory() as tmp:
            train_variant(
                run_params,
                variant,
                pairs,
                TrainOutputs(Path(tmp) / "model.pt", Path(tmp) / "ck.pt"),
                TrainOptions(progress=False, cache=cache),
            )

    return train


def main() -> None:
    args = _parser().parse_args()
    device = device_from(args.device)
    params = bench_params(args, load_params(args.params), device)
    t = params.train
    h, w = params.data.height, params.data.width
    cache, pairs = random_pairs(args.pairs, h, w)
    candidates = {
        f"{v} sync {s}": training_run(params, v, s, pairs, cache)
        for v in args.variants.split(",")
        for s in (1, args.sync)
    }
    timings = compare(candidates, device, repeats=args.repeats, warmup=args.warmup)
    images = args.pairs // t.batch_size * t.batch_size * args.epochs
    print(
        f"training loop, {args.pairs} pairs x {args.epochs} epochs, batch {t.batch_size}x3x{h}x{w}, "
        f"model x{params.model.width_multiplier}, {device}, {t.num_workers} workers, "
        f"{torch.get_num_threads()} threads, amp {t.amp}, channels_last {t.channels_last}, "
        f"median of {args.repeats}\n"
    )
    print(table(timings, next(iter(candidates)), unit_scale=1.0, unit="s"))
    print("\nimages/s: " + ", ".join(f"{n} {images / s:.1f}" for n, s in timings.medians().items()))


if __name__ == "__main__":
    main()
