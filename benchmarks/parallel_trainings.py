"""Trainings side by side against one after the other: what running the default's runs two at a time
would buy on a CPU (issue 52's headroom).

    python benchmarks/parallel_trainings.py                 # params.yaml's model, size and batch
    python benchmarks/parallel_trainings.py --epochs 2 --repeats 5

Candidates, interleaved per round (``_timing.compare``), each a fresh Python process per training
(``msdepth.training.train.train_variant`` on ``--pairs`` random pairs, as ``train_loop.py``):

- ``one after the other``: each variant's training in turn at ``--threads`` torch threads (default:
  the CPU count, what one training of the pipeline uses);
- ``side by side``: every variant's training at once, 1 thread each.

The ratio side by side / one after the other is the wall time for the same trainings, so its
inverse is the throughput gained. Process start-up is inside both, as it would be in a pipeline.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import subprocess
import sys
from pathlib import Path
from typing import Callable

import torch
from _timing import compare, table
from train_loop import bench_params, random_pairs, size_arguments, training_run

from msdepth.config.params import load_params


def parser() -> argparse.ArgumentParser:
    """The command line: sizes default to params.yaml's."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    size_arguments(ap)
    ap.add_argument("--pairs", type=int, default=800)
    ap.add_argument("--epochs", type=int, default=1)
    ap.add_argument("--variants", default="ssim,msssim", help="one training each, comma-separated")
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1, help="per training, one at a time")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--warmup", type=int, default=0)
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)  # one training, in this process
    return ap


def child_command(args: argparse.Namespace, variant: str, threads: int) -> list[str]:
    """This script run as one training of ``variant`` at ``threads`` torch threads."""
    sizes = ["--pairs", str(args.pairs), "--epochs", str(args.epochs), "--params", args.params]
    for flag, value in (
        ("--batch", args.batch),
        ("--height", args.height),
        ("--width", args.width),
        ("--width-multiplier", args.width_multiplier),
    ):
        sizes += [] if value is None else [flag, str(value)]
    return [
        sys.executable,
        str(Path(__file__).resolve()),
        "--child",
        variant,
        "--threads",
        str(threads),
        *sizes,
    ]


def run_children(commands: list[list[str]], at_once: bool) -> Callable[[], None]:
    """A candidate: the ``commands`` one after the other, or all started before any is waited for."""

    def run() -> None:
        if not at_once:
            for command in commands:
                subprocess.run(command, check=True)
            return
        procs = [subprocess.Popen(command) for command in commands]
        codes = [proc.wait() for proc in procs]
        if any(codes):
            raise SystemExit(f"a training failed: exit codes {codes}")

    return run


def train_one(args: argparse.Namespace) -> None:
    """``--child``: one training of ``args.child`` at ``args.threads`` threads, in this process."""
    args.workers, args.amp, args.channels_last = 0, "none", False  # train_loop's switches, off
    params = bench_params(args, load_params(args.params), torch.device("cpu"))
    params = dataclasses.replace(params, train=dataclasses.replace(params.train, threads=args.threads))
    cache, pairs = random_pairs(args.pairs, params.data.height, params.data.width)
    training_run(params, args.child, 1, pairs, cache)()


def main() -> None:
    args = parser().parse_args()
    if args.child is not None:
        train_one(args)
        return
    variants = args.variants.split(",")
    candidates = {
        f"one after the other, {args.threads} threads": run_children(
            [child_command(args, v, args.threads) for v in variants], at_once=False
        ),
        "side by side, 1 thread each": run_children(
            [child_command(args, v, 1) for v in variants], at_once=True
        ),
    }
    timings = compare(candidates, torch.device("cpu"), repeats=args.repeats, warmup=args.warmup)
    print(
        f"trainings of {', '.join(variants)}: {args.pairs} pairs x {args.epochs} epochs each, "
        f"{os.cpu_count()} CPUs, median of {args.repeats}\n"
    )
    baseline = next(iter(candidates))
    print(table(timings, baseline, unit_scale=1.0, unit="s"))
    ratio = timings.ratio("side by side, 1 thread each", baseline)[0]
    print(f"\nthroughput side by side / one after the other: {1 / ratio:.2f}x")


if __name__ == "__main__":
    main()
