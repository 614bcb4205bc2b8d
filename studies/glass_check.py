"""Non-glass pixels keep their bytes under a change of the glass model (docs/glass.md).

``dump`` renders frames of the synthetic set (``data.synthetic``) with whichever renderer is on
PYTHONPATH and saves their images and disparities; ``compare`` loads two dumps and, with the
current renderer's glass masks (:func:`msdepth.render.glass_pixels`), counts the pixels
that differ outside and inside glass::

    cd <old checkout> && python <this file copied there> dump /tmp/before --eval 40 --train 40
    python studies/glass_check.py dump /tmp/after --eval 40 --train 40
    python studies/glass_check.py compare /tmp/before /tmp/after
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from msdepth.config.params import read_params_file
from msdepth.errors import OutputError, run_main
from msdepth.io import save_npz
from msdepth.outputs import OutputPolicy
from msdepth.render import EVAL, TRAIN, render_frame

ROOT = Path(__file__).resolve().parents[1]

KEYS = ("left", "right", "disp", "disp_right", "class_map")


def frames(args: argparse.Namespace) -> list[tuple[int, int]]:
    """(split, index) of the frames to render."""
    return [(EVAL, i) for i in range(args.eval)] + [(TRAIN, i) for i in range(args.train)]


def dump(args: argparse.Namespace, s: dict) -> None:
    """Render and save each frame's images and GT, every file claimed first (output policy)."""
    out = Path(args.a)
    paths = {(split, i): out / f"{split}_{i:06d}.npz" for split, i in frames(args)}
    OutputPolicy(out, "glass-check").claim(list(paths.values()), ROOT / "params.yaml")
    for (split, i), path in paths.items():
        f = render_frame(s["seed"], split, i, s["height"], s["width"])
        save_npz(path, **{k: getattr(f, k) for k in KEYS})


def compare(args: argparse.Namespace, s: dict) -> int:
    """Print per-split counts of differing bytes outside and inside glass; 1 if any outside, else 0."""
    from msdepth.render import glass_pixels  # only the new renderer has it

    totals = {}
    for split, i in frames(args):
        a, b = (np.load(Path(d) / f"{split}_{i:06d}.npz") for d in (args.a, args.b))
        masks = glass_pixels(s["seed"], split, i, s["height"], s["width"])
        t = totals.setdefault(split, np.zeros(6, np.int64))
        for key in ("disp", "disp_right", "class_map"):
            t[0] += int((a[key] != b[key]).sum())  # geometry and GT: must not change at all
        for key, mask in zip(("left", "right"), masks, strict=True):
            diff = (a[key] != b[key]).any(axis=2)
            t[1:] += [(diff & ~mask).sum(), (~mask).sum(), (diff & mask).sum(), mask.sum(), 1]
    for split, t in totals.items():
        name = "eval" if split == EVAL else "train"
        print(
            f"{name}: {t[5] // 2} frames; GT/disparity values changed {t[0]}; non-glass pixels changed "
            f"{t[1]} of {t[2]}; glass pixels changed {t[3]} of {t[4]}"
        )
    return 1 if any(t[0] or t[1] for t in totals.values()) else 0


def main(argv: list[str] | None = None) -> int:
    """Command line: dump DIR | compare DIR_A DIR_B."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=("dump", "compare"))
    ap.add_argument("a")
    ap.add_argument("b", nargs="?")
    ap.add_argument("--eval", type=int, default=40)
    ap.add_argument("--train", type=int, default=40)
    args = ap.parse_args(argv)
    s = read_params_file(ROOT / "params.yaml")["data"]["synthetic"]
    if args.mode == "compare":
        return compare(args, s)
    try:
        dump(args, s)
    except OutputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/glass_check.py", main))
