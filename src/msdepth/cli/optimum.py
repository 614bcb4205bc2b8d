"""``msdepth optimum LEFT RIGHT --variant NAME --out DIR``: the losses' own optimum of any stereo pair.

Kept apart from :mod:`msdepth.optimum.solver` so that building the parser (``msdepth --help``) imports
no torch. Writes, per pair, what ``msdepth predict`` writes for a frame (its own writer,
:func:`msdepth.cli.predict.save_outputs`): ``<stem>_disp.npy`` (disparity in px at LEFT's
resolution, float32), ``<stem>_disp.png`` and ``<stem>_depth.npy`` (metres).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Callable

import yaml

from msdepth.cli.options import camera_options
from msdepth.config.params import Params, apply_overrides, params_from_dict
from msdepth.errors import ConfigError, DataError, MsdepthError


def optimum_command(add_parser: Callable[..., argparse.ArgumentParser]) -> None:
    """Add the ``optimum`` subcommand with ``add_parser`` (``msdepth``'s subparsers' own method)."""
    o = add_parser(
        "optimum",
        help="the disparity a loss variant prefers for a stereo pair, optimised directly (no network)",
        description="Per stereo pair, optimise a left and a right disparity map to minimise a loss variant's "
        "training objective (docs/optimum.md), and write what 'msdepth predict' writes: <stem>_disp.npy "
        "(px, at LEFT's resolution), <stem>_disp.png and <stem>_depth.npy (m). LEFT and RIGHT are two "
        "images, or two folders holding images of the same names.",
    )
    o.add_argument("left", metavar="LEFT", help="left image, or folder of left images")
    o.add_argument("right", metavar="RIGHT", help="right image, or folder of right images of the same names")
    o.add_argument("--variant", required=True, help="loss variant, e.g. ssim or msssim")
    o.add_argument("--out", required=True, help="output folder")
    o.add_argument(
        "--params", help="params file (default: ./params.yaml when it exists, else the built-in defaults)"
    )
    o.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a params override, e.g. msssim.kernel_size=7",
    )
    camera_options(o, principal_point=False)
    o.add_argument("--height", type=int, help="working height (default: optimum.height, else the image's)")
    o.add_argument("--width", type=int, help="working width (default: optimum.width, else the image's)")
    o.add_argument(
        "--start",
        metavar="{constant,cost,sgbm}",
        help="where the optimum starts (default: optimum.start): a constant, refined coarse to fine; or "
        "a matched start, refined at the finest level: SGM on the variant's own cost volume (cost) or "
        "OpenCV's SGBM (sgbm), matched at the image's own size",
    )
    o.add_argument("--quiet", action="store_true", help="no progress bar")
    o.set_defaults(run=run)


def read_params(path: str | None, assignments: list[str]) -> Params:
    """``path`` (or ./params.yaml, or the defaults) with the ``--set`` assignments, validated."""
    source = Path(path) if path else Path("params.yaml")
    raw: dict = {}
    if path or source.is_file():
        if not source.is_file():
            raise ConfigError(f"{source}: no such params file")
        try:
            raw = yaml.safe_load(source.read_text()) or {}
        except yaml.YAMLError as exc:
            raise ConfigError(f"{source}: not valid YAML: {exc}") from None
    return params_from_dict(apply_overrides(raw, assignments))


def stereo_pairs(left: Path, right: Path) -> list[tuple[Path, Path, Path]]:
    """``(left image, right image, output stem)`` of two images or two folders (recursive,
    sorted; a right image is expected at the left one's relative path)."""
    from msdepth.cli.predict import IMAGE_EXTENSIONS

    if left.is_file() and right.is_file():
        return [(left, right, Path(left.stem))]
    if left.is_dir() and right.is_dir():
        files = sorted(p for p in left.rglob("*") if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS)
        if not files:
            raise DataError(f"{left}: no images in this folder or below")
        return [(p, right / p.relative_to(left), p.relative_to(left).with_suffix("")) for p in files]
    for path in (left, right):
        if not path.exists():
            raise DataError(f"{path}: no such file or folder")
    raise DataError(f"{left} and {right}: give two images or two folders, not one of each")


def requested_size(args: argparse.Namespace, params: Params) -> tuple[int, int] | None:
    """The working size asked for, checked: ``--height``/``--width``, else ``optimum.height``/``width``,
    else None (each image's own; :func:`msdepth.optimum.solver.working_size` resolves it per pair)."""
    height, width = args.height or params.optimum.height, args.width or params.optimum.width
    if bool(height) != bool(width):
        raise ConfigError("optimum: give both a working height and width (--height/--width), or neither")
    if height and min(height, width) < 24:
        raise ConfigError(f"optimum: the working size {height}x{width} is below 24 px")
    return (height, width) if height else None


def run(args: argparse.Namespace) -> int:
    """The ``optimum`` subcommand: exit code 0, or 1 when a pair failed (each named on stderr)."""
    from msdepth.cli.predict import PredictOptions, save_outputs
    from msdepth.data.kitti import read_image
    from msdepth.data.pairs import check_same_size
    from msdepth.optimum.solver import objective, optimum_disparities

    # --start is optimum.start's override, checked (one line) as the params file's value is.
    params = read_params(args.params, [*args.set, *([f"optimum.start={args.start}"] if args.start else [])])
    size = requested_size(args, params)
    objective(params, args.variant)  # an unknown variant fails before any image is read
    given = {k: v for k, v in (("focal", args.focal), ("baseline", args.baseline)) if v is not None}
    options = PredictOptions(disp_format="both", depth_format="npy", progress=False, **given)
    failed = 0

    def fail(exc: Exception) -> None:
        nonlocal failed
        print(f"error: {' '.join(str(exc).splitlines())}", file=sys.stderr)
        failed += 1

    good = []
    for left_path, right_path, stem in stereo_pairs(Path(args.left), Path(args.right)):
        try:
            left, right = read_image(left_path), read_image(right_path)
            check_same_size(left_path, left.shape, right_path, right.shape, "right image")
            good.append((stem, left, right))
        except DataError as exc:
            fail(exc)
    read_failed = failed
    pairs = [(left, right) for _, left, right in good]
    disps = optimum_disparities(pairs, params, args.variant, size=size, progress=not args.quiet)
    for (stem, left, _), disp in zip(good, disps, strict=True):
        try:
            save_outputs(Path(args.out) / stem, left, disp, options)
        except (MsdepthError, OSError) as exc:
            fail(exc)
    print(
        f"wrote the optimum of {len(good) + read_failed - failed} of {len(good) + read_failed} pair(s) "
        f"to {args.out}",
        file=sys.stderr,
    )
    return 1 if failed else 0
