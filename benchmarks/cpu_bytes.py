"""Do environment settings that pin torch's CPU kernels make training byte-identical across
thread counts, and what do they cost?

    python benchmarks/cpu_bytes.py                 # params.yaml's model and size, 1 and 2 threads
    python benchmarks/cpu_bytes.py --pairs 32 --epochs 1 --repeats 3

Trained bytes depend on the CPU (its vector width picks ATen's and oneDNN's kernels) and on
``train.threads`` (the threads split reductions, so float sums round differently). Each
candidate below is an environment setting read when torch loads, so every run is a fresh
``python`` process: it trains one seed of one variant (``msdepth.training.train.train_variant``,
from scratch, on ``--pairs`` random pairs held in memory, as ``train_loop.py``) and prints the
SHA-256 of the saved weights and its training seconds. Settings tried:

- ``ATEN_CPU_CAPABILITY=default``: ATen's scalar kernels instead of AVX2/AVX-512;
- ``ONEDNN_MAX_CPU_ISA=SSE41``: oneDNN's convolutions limited to SSE4.1;
- ``MKL_CBWR=COMPATIBLE``: MKL's conditional numerical reproducibility;
- all three together.

The table gives per setting the weights' hash at each thread count (equal hashes: identical
bytes), and the time ratio to no setting at the same thread count (runs interleaved, medians
over rounds). A setting is worth adopting only if its hashes agree across thread counts (or
match no setting's on a second CPU) at a cost of at most 10 %.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SETTINGS = {
    "none": {},
    "ATEN_CPU_CAPABILITY=default": {"ATEN_CPU_CAPABILITY": "default"},
    "ONEDNN_MAX_CPU_ISA=SSE41": {"ONEDNN_MAX_CPU_ISA": "SSE41"},
    "MKL_CBWR=COMPATIBLE": {"MKL_CBWR": "COMPATIBLE"},
    "all three": {"ATEN_CPU_CAPABILITY": "default", "ONEDNN_MAX_CPU_ISA": "SSE41", "MKL_CBWR": "COMPATIBLE"},
}
PINNED = tuple(SETTINGS["all three"])  # removed from the parent's environment for "none"


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--params", default=str(Path(__file__).resolve().parents[1] / "params.yaml"))
    ap.add_argument("--variant", default="msssim")
    ap.add_argument("--pairs", type=int, default=32)
    ap.add_argument("--epochs", type=int, default=1)
    ap.add_argument("--threads", default="1,2", help="comma-separated thread counts")
    ap.add_argument("--settings", default=",".join(SETTINGS), help="comma-separated names of SETTINGS")
    ap.add_argument("--repeats", type=int, default=2, help="interleaved rounds (time: median over them)")
    ap.add_argument("--child", type=int, default=0, help=argparse.SUPPRESS)  # one run with this many threads
    return ap


def child(args: argparse.Namespace) -> None:
    """One training from scratch with ``args.child`` threads: print '<sha256> <seconds>'."""
    import torch
    from train_loop import random_pairs

    from msdepth.config.params import load_params
    from msdepth.training.train import TrainOptions, TrainOutputs, train_variant

    base = load_params(args.params)
    train = dataclasses.replace(
        base.train, seeds=(0,), epochs=args.epochs, threads=args.child, device="cpu", compile=False
    )
    params = dataclasses.replace(base, train=train)
    cache, pairs = random_pairs(args.pairs, base.data.height, base.data.width)
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        outputs = TrainOutputs(Path(tmp) / "model.pt", Path(tmp) / "ck.pt")
        train_variant(params, args.variant, pairs, outputs, TrainOptions(progress=False, cache=cache))
        seconds = time.perf_counter() - start
        state = torch.load(Path(tmp) / "model.pt", map_location="cpu", weights_only=True)
    weights = state.get("model", state) if isinstance(state, dict) else state
    digest = hashlib.sha256()
    for name in sorted(k for k, v in weights.items() if torch.is_tensor(v)):
        digest.update(name.encode() + weights[name].cpu().contiguous().numpy().tobytes())
    print(f"{digest.hexdigest()} {seconds:.3f}")


def run_child(args: argparse.Namespace, setting: str, threads: int) -> tuple[str, float]:
    """A fresh process with ``setting``'s environment: (weights' hash, training seconds)."""
    env = {k: v for k, v in os.environ.items() if k not in PINNED}
    env.update(SETTINGS[setting])
    cmd = [sys.executable, __file__, "--child", str(threads), "--params", args.params]
    cmd += ["--variant", args.variant, "--pairs", str(args.pairs), "--epochs", str(args.epochs)]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if out.returncode:
        raise SystemExit(f"{setting}, {threads} threads: failed\n{out.stderr[-2000:]}")
    digest, seconds = out.stdout.split()[-2:]
    return digest, float(seconds)


def main() -> None:
    args = _parser().parse_args()
    if args.child:
        return child(args)
    names = args.settings.split(",")
    unknown = [n for n in names if n not in SETTINGS]
    if unknown:
        raise SystemExit(f"--settings: unknown {unknown}; known: {list(SETTINGS)}")
    counts = [int(t) for t in args.threads.split(",")]
    hashes: dict[tuple[str, int], set[str]] = {}
    times: dict[tuple[str, int], list[float]] = {}
    for _ in range(args.repeats):
        for threads in counts:
            for name in names:
                digest, seconds = run_child(args, name, threads)
                hashes.setdefault((name, threads), set()).add(digest)
                times.setdefault((name, threads), []).append(seconds)
    print(f"{args.variant}, {args.pairs} random pairs x {args.epochs} epoch(s), median of {args.repeats}\n")
    print(
        "| setting | " + " | ".join(f"{t} threads: hash, s, time / none" for t in counts) + " | same bytes |"
    )
    print("|---|" + "---|" * len(counts) + "---|")
    for name in names:
        cells, digests = [], set()
        for t in counts:
            median = statistics.median(times[(name, t)])
            ratio = median / statistics.median(times[("none", t)]) if "none" in names else float("nan")
            shown = ",".join(sorted(h[:12] for h in hashes[(name, t)]))
            cells.append(f"{shown}, {median:.1f}, {ratio:.3f}")
            digests |= hashes[(name, t)]
        print(f"| {name} | " + " | ".join(cells) + f" | {'yes' if len(digests) == 1 else 'no'} |")


if __name__ == "__main__":
    main()
