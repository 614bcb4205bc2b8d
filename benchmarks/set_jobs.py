"""Frames in worker processes against threads in one: what ``optimum.jobs`` buys an extra set's
network-free instruments (issue 55) on a CPU.

    python benchmarks/set_jobs.py                       # the real samples in ../shared, else generated
    python benchmarks/set_jobs.py --frames DIR --repeats 3 --copies 1

Candidates, interleaved per round (``_timing.compare``), each running the lean default's five
instruments (SGM on each variant's cost volume, OpenCV's SGBM, each variant's optimum at
``optimum.smoothness_weight``) over the same frames through
:func:`msdepth.optimum.sets.frame_disparities`, as the set stages do, process start-up included:

- ``1 job x N threads``: one frame at a time, ``--threads`` torch threads (default: the CPU count);
- ``N jobs x 1 thread``: ``--threads`` frames at once in spawned workers, 1 thread each.

Frames: every ``*.png`` pair of ``--frames`` (``image_2``/``image_3`` or ``colored_0``/``colored_1``
below it, KITTI 2015 and 2012's layouts), by default ``../shared/real-samples``; without any, 4
generated textured pairs at KITTI's 375 x 1242 (``--size``). Each is listed ``--copies`` times, so
that a worker's start-up (about 2 s per stage) weighs as little as on a real set's hundreds of
frames. Prints seconds per frame and the ratio.
"""

from __future__ import annotations

import argparse
import itertools
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import torch
from _timing import compare, table

from msdepth.config.params import load_params
from msdepth.data import kitti2012
from msdepth.io import write_png
from msdepth.optimum.sets import SetInstrument, frame_disparities

SAMPLES = Path(__file__).resolve().parents[2] / "shared" / "real-samples"
LAYOUTS = (("image_2", "image_3"), (kitti2012.LEFT, kitti2012.RIGHT))  # KITTI 2015, 2012


def sample_pairs(root: Path) -> list[tuple[Path, Path]]:
    """Every left/right pair of a KITTI 2012 or 2015 layout below ``root``."""
    pairs = []
    for left_dir, right_dir in LAYOUTS:
        for left in sorted(root.rglob(f"{left_dir}/*.png")):
            right = left.parent.parent / right_dir / left.name
            if right.is_file():
                pairs.append((left, right))
    return pairs


def generated_pairs(
    folder: Path, count: int = 4, height: int = 375, width: int = 1242
) -> list[tuple[Path, Path]]:
    """``count`` textured pairs at a 20 px disparity, KITTI-sized, written below ``folder``."""
    rng, pairs = np.random.default_rng(0), []
    for n in range(count):
        noise = rng.integers(0, 255, (height // 4, (width + 20) // 4, 3), dtype=np.uint8)
        scene = cv2.resize(noise, (width + 20, height), interpolation=cv2.INTER_CUBIC)
        left, right = folder / f"{n}_l.png", folder / f"{n}_r.png"
        write_png(left, scene[:, :width])
        write_png(right, scene[:, 20:])
        pairs.append((left, right))
    return pairs


def lean_instruments(params) -> list[SetInstrument]:
    """The lean default's instruments of an extra set, as its stages build them."""
    weight = params.optimum.smoothness_weight
    found = [SetInstrument(params, "cost", v) for v in params.variants]
    found.append(SetInstrument(params, "sgbm", "sgbm"))
    return found + [SetInstrument(params, "optimum", v, weight) for v in params.variants]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=Path, default=SAMPLES)
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--size", default="375x1242", help="the generated frames' HxW (no --frames pairs)")
    ap.add_argument(
        "--copies", type=int, default=3, help="each frame listed this many times (start-up amortised)"
    )
    args = ap.parse_args()
    params = load_params(args.params)
    with tempfile.TemporaryDirectory() as tmp:
        pairs = sample_pairs(args.frames) if args.frames.is_dir() else []
        height, width = (int(side) for side in args.size.split("x"))
        pairs = (pairs or generated_pairs(Path(tmp), 4, height, width)) * args.copies
        index = pd.DataFrame(
            {
                "left": [str(a) for a, _ in pairs],
                "right": [str(b) for _, b in pairs],
                "frame": range(len(pairs)),
            }
        )
        instruments = lean_instruments(params)
        runs = itertools.count()

        def candidate(jobs: int, threads: int):
            def run() -> None:
                torch.set_num_threads(threads)
                for instrument in instruments:
                    folder = Path(tmp) / f"run{next(runs)}"
                    folder.mkdir()
                    frame_disparities(index, folder, instrument, instrument.start, jobs, threads)

            return run

        n = args.threads
        candidates = {f"1 job x {n} threads": candidate(1, n), f"{n} jobs x 1 thread": candidate(n, 1)}
        timings = compare(candidates, torch.device("cpu"), repeats=args.repeats, warmup=0)
    source = "generated" if pairs[0][0].is_relative_to(tmp) else str(args.frames)
    print(f"{len(pairs)} frames ({source}, x{args.copies}), {len(instruments)} instruments")
    print(f"{os.cpu_count()} CPUs; seconds per frame, the instruments together:")
    print(table(timings, f"1 job x {n} threads", unit_scale=1 / len(pairs), unit="s"))


if __name__ == "__main__":
    main()
