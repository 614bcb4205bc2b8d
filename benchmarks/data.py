"""Training pairs per second the loader delivers (decode, resize, augment) with N workers.

    python benchmarks/data.py                       # params.yaml's index, size and batch
    python benchmarks/data.py --workers 0,1,2,4,8

Reads the pairs of ``data/index/train_pairs.txt`` (run ``dvc repro index`` first). Each worker
count is timed over the same number of batches, after one warm-up batch (worker start-up is
reported separately, since persistent workers pay it once per run).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch
from torch.utils.data import DataLoader

from msdepth.config.params import load_params
from msdepth.data.pairs import StereoPairs, load_pair_list

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--params", default=str(ROOT / "params.yaml"))
    ap.add_argument("--index", default=str(ROOT / "data" / "index" / "train_pairs.txt"))
    ap.add_argument("--workers", default="0,1,2")
    ap.add_argument("--batches", type=int, default=40)
    args = ap.parse_args()
    params = load_params(args.params)
    pairs = load_pair_list(args.index)
    pairs = [
        (ROOT / a if not a.is_absolute() else a, ROOT / b if not b.is_absolute() else b) for a, b in pairs
    ]
    dataset = StereoPairs(pairs, params.data.height, params.data.width, augment=params.train.augment, seed=0)
    batch = params.train.batch_size
    print(
        f"loader: {len(pairs)} pairs -> {params.data.height}x{params.data.width}, batch {batch}, "
        f"augment {params.train.augment}\n"
    )
    print("| workers | start-up s | pairs/s | relative to 0 workers |\n|---|---|---|---|")
    base = None
    for workers in (int(w) for w in args.workers.split(",")):
        loader = DataLoader(
            dataset,
            batch_size=batch,
            shuffle=True,
            num_workers=workers,
            generator=torch.Generator().manual_seed(0),
            drop_last=True,
        )
        started = time.perf_counter()
        it = iter(loader)
        next(it)
        startup = time.perf_counter() - started
        started = time.perf_counter()
        n = 0
        for _ in range(args.batches):
            try:
                n += next(it)["left"].shape[0]
            except StopIteration:
                break
        rate = n / (time.perf_counter() - started)
        base = base or rate
        print(f"| {workers} | {startup:.2f} | {rate:.0f} | {rate / base:.2f} |")
        del it, loader


if __name__ == "__main__":
    main()
