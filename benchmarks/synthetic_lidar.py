"""What the simulated Velodyne scans add to ``render.generate``: with scans on and off, side by side.

    python benchmarks/synthetic_lidar.py                  # params.yaml's data.synthetic, 8 + 8 frames
    python benchmarks/synthetic_lidar.py --train 8 --eval 8 --repeats 5

Both candidates render the same small set (``--train`` training pairs, ``--eval`` evaluation
frames at params.yaml's render size, one process), interleaved round by round. The difference
is the scans' cost per evaluation frame (ray casting, the raw-drive copies of the images, the
.bin file, the projected GT count); the share of the full set is extrapolated from it:
``eval_frames * added per eval frame / (full set's frames * time per frame without scans)``.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

import torch
from _timing import compare, table

from msdepth import render
from msdepth.config.params import load_params

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--params", default=str(ROOT / "params.yaml"))
    ap.add_argument("--train", type=int, default=8, help="training pairs rendered per call")
    ap.add_argument("--eval", type=int, default=8, help="evaluation frames rendered per call")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    full = load_params(args.params).data.synthetic
    cfg = dataclasses.replace(full, train_pairs=args.train, eval_frames=args.eval, drives=1)
    with tempfile.TemporaryDirectory() as tmp:
        roots = {name: Path(tmp) / name for name in ("off", "on")}
        timings = compare(
            {
                name: (lambda r=root, on=(name == "on"): render.generate(cfg, r, False, 1, lidar=on))
                for name, root in roots.items()
            },
            torch.device("cpu"),
            repeats=args.repeats,
            warmup=1,
        )
    off, on = timings.median("off"), timings.median("on")
    per_frame = off / (cfg.train_pairs + cfg.eval_frames)
    added = (on - off) / cfg.eval_frames
    share = full.eval_frames * added / ((full.train_pairs + full.eval_frames) * per_frame)
    print(
        f"generate, {cfg.train_pairs} training pairs + {cfg.eval_frames} evaluation frames at "
        f"{cfg.height}x{cfg.width}, 1 process, {args.repeats} interleaved rounds\n"
    )
    print(table(timings, "off", unit_scale=1.0, unit="s"))
    print(
        f"\nper frame without scans: {per_frame * 1e3:.1f} ms; added per evaluation frame: "
        f"{added * 1e3:.1f} ms ({added / per_frame:.0%} of a frame)\n"
        f"full set ({full.train_pairs} + {full.eval_frames} frames): "
        f"+{full.eval_frames * added:.1f} s on {(full.train_pairs + full.eval_frames) * per_frame:.0f} s "
        f"= +{share:.1%}"
    )


if __name__ == "__main__":
    main()
