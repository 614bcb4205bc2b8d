"""``msdepth photometry``: how real stereo pairs look to a photometric loss, as a reference table.

Measures each frame of KITTI 2015 or 2012 training folders (:mod:`msdepth.evaluation.photometry`)
at one width and writes one CSV row per frame. The pipeline's ``photometry`` stage compares the
rendered evaluation frames with such a table (``photometry.reference``); the committed one,
``data_lists/photometry_kitti.csv``, was measured on real KITTI frames (data_lists/SOURCE.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Callable

from msdepth.errors import ConfigError

DEFAULT_WIDTH = 414  # the synthetic set's render width (data.synthetic.width)
MAX_WIDTH = 4096


def photometry_command(add_parser: Callable[..., argparse.ArgumentParser]) -> None:
    """Add the ``photometry`` subcommand with ``add_parser`` (``msdepth``'s subparsers' own method)."""
    p = add_parser(
        "photometry",
        help="photometric statistics of real stereo pairs with GT (a reference for the photometry stage)",
        description="Measure every *_10.png frame of each FOLDER (KITTI 2015 training: image_2/, image_3/, "
        "disp_occ_0/; KITTI 2012 training: colored_0/, colored_1/, disp_occ/; or the folder holding "
        "training/) at --width px wide: the GT-warp residual, the views' brightness gap, mean grey and "
        "spread, noise sigma, gradient energy and SSIM at the GT disparity. One CSV row per frame.",
    )
    p.add_argument("folders", nargs="+", metavar="FOLDER", help="KITTI 2015 or 2012 training folder")
    p.add_argument("--out", required=True, help="CSV file to write")
    p.add_argument(
        "--width",
        type=int,
        default=DEFAULT_WIDTH,
        help=f"measure at this width, the aspect kept (default: {DEFAULT_WIDTH}, the render width)",
    )
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Measure the folders and write the CSV (through the output policy, atomically)."""
    import pandas as pd

    from msdepth.evaluation.photometry import measure_real
    from msdepth.io import atomic_path
    from msdepth.outputs import output_file_policy

    if not 16 <= args.width <= MAX_WIDTH:
        raise ConfigError(f"--width: must be 16 to {MAX_WIDTH} px, got {args.width}")
    policy = output_file_policy(args.out, "photometry", tuple(args.folders))
    policy.claim([Path(args.out)], args.folders[0])
    table = pd.concat([measure_real(folder, args.width) for folder in args.folders], ignore_index=True)
    with atomic_path(args.out, suffix=".csv") as tmp:
        table.to_csv(tmp, index=False, float_format="%.6g")
    policy.settle()
    print(f"wrote {args.out}: {len(table)} frame(s) at {args.width} px wide", file=sys.stderr)
    return 0
