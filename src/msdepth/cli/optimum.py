"""``msdepth optimum LEFT RIGHT --variant NAME --out DIR``: the losses' own optimum of any stereo pair.

Kept apart from :mod:`msdepth.optimum.solver` so that building the parser (``msdepth --help``) imports
no torch. Writes, per pair, what ``msdepth predict`` writes for a frame (its own writer,
:func:`msdepth.cli.predict.save_outputs`), named after the variant too, so that both variants'
results of a pair sit side by side in one folder: ``<stem>_<variant>_disp.npy`` (disparity in px at
LEFT's resolution, float32), ``<stem>_<variant>_disp.png`` and ``<stem>_<variant>_depth.npy`` (metres).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from msdepth.cli.options import camera_options
from msdepth.config.params import (
    MAX_OPTIMUM_SIDE,
    MAX_WEIGHT,
    OptimumConfig,
    Params,
    apply_overrides,
    params_from_dict,
    read_params_file,
)
from msdepth.errors import ConfigError, DataError, MsdepthError, PixelLimitError
from msdepth.outputs import OutputPolicy

if TYPE_CHECKING:
    import numpy as np

    from msdepth.cli.predict import PredictOptions

# Adam steps per level without a params file: the instrument's measured stopping rule
# (docs/optimum.md, "Stopping rule"); params.yaml's 50 fits the pipeline's time budget.
INSTRUMENT_ITERATIONS = 100
MAX_VMAX = 1e5  # px: --vmax's bound, wider than any image the command reads


def optimum_command(add_parser: Callable[..., argparse.ArgumentParser]) -> None:
    """Add the ``optimum`` subcommand with ``add_parser`` (``msdepth``'s subparsers' own method)."""
    o = add_parser(
        "optimum",
        help="the disparity a loss variant prefers for a stereo pair, optimised directly (no network)",
        description="Per stereo pair, optimise a left and a right disparity map to minimise a loss variant's "
        "training objective (docs/optimum.md), and write what 'msdepth predict' writes, named after the "
        "variant: <stem>_<variant>_disp.npy (px, at LEFT's resolution), <stem>_<variant>_disp.png and "
        "<stem>_<variant>_depth.npy (m). LEFT and RIGHT are two images, or two folders holding images of "
        "the same names.",
    )
    o.add_argument("left", metavar="LEFT", help="left image, or folder of left images")
    o.add_argument("right", metavar="RIGHT", help="right image, or folder of right images of the same names")
    o.add_argument("--variant", required=True, help="loss variant, e.g. ssim or msssim")
    o.add_argument("--out", required=True, help="output folder")
    o.add_argument(
        "--params",
        help="params file (default: ./params.yaml when it exists, else the built-in defaults with "
        f"optimum.iterations {INSTRUMENT_ITERATIONS}, the measured stopping rule)",
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
        "OpenCV's SGBM (sgbm), matched at the image's own size (halved within optimum.max_width)",
    )
    o.add_argument(
        "--device",
        choices=("cpu", "cuda", "auto"),
        help="where the refinement runs (default: train.device); the matchers run on the CPU",
    )
    o.add_argument(
        "--colorbar",
        action="store_true",
        help="one colour scale for a pair's disparity PNGs of every variant in --out (this run's and "
        "those already there, redrawn: min to the largest 95th percentile), with a colour bar in px",
    )
    o.add_argument(
        "--vmax",
        type=float,
        metavar="PX",
        help="a fixed colour scale for every disparity PNG, 0 to PX px (runs into different folders "
        "compare too); with --colorbar, its bar",
    )
    o.add_argument("--quiet", action="store_true", help="no progress bar")
    o.set_defaults(run=run)


# optimum's keys that only the pipeline reads (the extra sets' weights, the sweep stage's) and
# that must hold optimum.smoothness_weight: on the command line they follow the weight given.
PIPELINE_WEIGHT_LISTS = ("set_weights", "smoothness_sweep")


def _read_params(path: str | None, assignments: list[str]) -> Params:
    """``path`` (or ./params.yaml, or the defaults with ``optimum.iterations``
    :data:`INSTRUMENT_ITERATIONS`) with the ``--set`` assignments, validated: the hardened reader
    and checks of every params file (:func:`msdepth.config.params.read_params_file`). The
    pipeline-only weight lists (:data:`PIPELINE_WEIGHT_LISTS`) follow ``optimum.smoothness_weight``
    unless an assignment sets them (:func:`_weights_follow`)."""
    source = Path(path) if path else Path("params.yaml")
    if path or source.is_file():
        raw = read_params_file(source)
    else:
        source, raw = None, {"optimum": {"iterations": INSTRUMENT_ITERATIONS}}
    try:
        raw = apply_overrides(raw, assignments)
        return _weights_follow(raw, assignments)
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}" if source else str(exc)) from None


def _weights_follow(raw: dict, assignments: list[str]) -> Params:
    """``raw`` validated with ``optimum.set_weights`` and ``smoothness_sweep`` (the pipeline's, read
    by no command) made to hold ``optimum.smoothness_weight``; a list an assignment names is kept as
    given. A weight 0, which no sweep may hold, is checked as the default weight, then set."""
    section = raw.get("optimum")
    weight = section.get("smoothness_weight") if isinstance(section, dict) else None
    if not _is_number(weight) or not 0 <= weight <= MAX_WEIGHT:
        return params_from_dict(raw)  # absent, or its own check's one line
    named = {a.partition("=")[0].strip() for a in assignments}
    defaults = OptimumConfig()
    checked = weight or defaults.smoothness_weight
    section["smoothness_weight"] = checked
    for key in PIPELINE_WEIGHT_LISTS:
        listed = section.get(key, getattr(defaults, key))
        if f"optimum.{key}" in named or not isinstance(listed, list | tuple):
            continue
        if all(_is_number(w) and 0 < w <= MAX_WEIGHT for w in listed):  # else their own check's line
            followed = {checked} if key == "set_weights" else {*listed, checked}
            section[key] = sorted(map(float, followed))
    params = params_from_dict(raw)
    optimum = dataclasses.replace(params.optimum, smoothness_weight=float(weight))
    return dataclasses.replace(params, optimum=optimum)


def _is_number(value: object) -> bool:
    """An int or float, not a bool."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _stereo_pairs(left: Path, right: Path, skip: Path | None = None) -> list[tuple[Path, Path, Path]]:
    """``(left image, right image, output stem)`` of two images or two folders (recursive,
    sorted; a right image is expected at the left one's relative path; files under ``skip``, the
    output folder, are not listed). LEFT and RIGHT the same file or folder is refused."""
    from msdepth.cli.predict import IMAGE_EXTENSIONS

    if left.exists() and right.exists() and left.resolve() == right.resolve():
        raise DataError(f"{left} and {right}: LEFT and RIGHT are the same, not a stereo pair")
    if left.is_file() and right.is_file():
        return [(left, right, Path(left.stem))]
    if left.is_dir() and right.is_dir():
        files = sorted(
            p
            for p in left.rglob("*")
            if p.is_file()
            and p.suffix.lower() in IMAGE_EXTENSIONS
            and not (skip and p.resolve().is_relative_to(skip.resolve()))
        )
        if not files:
            raise DataError(f"{left}: no images in this folder or below")
        return [(p, right / p.relative_to(left), p.relative_to(left).with_suffix("")) for p in files]
    for path in (left, right):
        if not path.exists():
            raise DataError(f"{path}: no such file or folder")
    raise DataError(f"{left} and {right}: give two images or two folders, not one of each")


def _output_stem(out: Path, stem: Path, variant: str) -> Path:
    """Where a pair's outputs go: ``out/<stem>_<variant>`` (then ``_disp.npy`` etc.). The variant in
    the name keeps one variant's result from replacing another's in a shared folder, the comparison
    the command is for."""
    return out / stem.with_name(f"{stem.name}_{variant}")


def _requested_size(args: argparse.Namespace, params: Params) -> tuple[int, int] | None:
    """The working size asked for, checked: ``--height``/``--width``, else ``optimum.height``/``width``,
    else None (each image's own; :func:`msdepth.optimum.solver.working_size` resolves it per pair)."""
    height, width = args.height or params.optimum.height, args.width or params.optimum.width
    if bool(height) != bool(width):
        raise ConfigError("optimum: give both a working height and width (--height/--width), or neither")
    if height and min(height, width) < 24:
        raise ConfigError(f"optimum: the working size {height}x{width} is below 24 px")
    if height and max(height, width) > MAX_OPTIMUM_SIDE:
        raise ConfigError(f"optimum: the working size {height}x{width} is over {MAX_OPTIMUM_SIDE} px a side")
    return (height, width) if height else None


def run(args: argparse.Namespace) -> int:
    """The ``optimum`` subcommand: exit code 0, or 1 when a pair failed (each named on stderr).

    Pairs are read, optimised and written ``optimum.batch_size`` at a time (fewer when their
    images reach :data:`msdepth.data.imagefile.BATCH_PIXEL_BUDGET` pixels), so a run killed
    midway keeps the pairs it finished; every output goes through :class:`msdepth.outputs.OutputPolicy`.
    """
    from msdepth.cli.predict import PredictOptions
    from msdepth.data.imagefile import batches_by_pixels, file_pixels
    from msdepth.networks.device import resolve_device
    from msdepth.optimum.solver import objective

    # --start and --device are overrides of optimum.start and train.device, checked (one line) as
    # the params file's values are.
    flags = [f"optimum.start={args.start}"] if args.start else []
    flags += [f"train.device={args.device}"] if args.device else []
    params = _read_params(args.params, [*args.set, *flags])
    size = _requested_size(args, params)
    if args.vmax is not None and not 0 < args.vmax <= MAX_VMAX:
        raise ConfigError(
            f"--vmax: must be a disparity in px, above 0 and at most {MAX_VMAX:g}, got {args.vmax}"
        )
    objective(params, args.variant)  # an unknown variant fails before any image is read
    resolve_device(params.train.device)  # so does a CUDA device torch does not see
    given = {k: v for k, v in (("focal", args.focal), ("baseline", args.baseline)) if v is not None}
    options = PredictOptions(disp_format="both", depth_format="npy", progress=False, **given)
    left, right, out = Path(args.left), Path(args.right), Path(args.out)
    policy = OutputPolicy(out, "optimum", input_dirs=(left, right))
    pairs = _stereo_pairs(left, right, out)
    policy.protect([p for pair in pairs for p in pair[:2]])
    policy.prepare()
    failed = 0
    # planned by memory from the headers: at most optimum.batch_size pairs, closed at
    # BATCH_PIXEL_BUDGET decoded pixels (a pair holds two images)
    for chunk in batches_by_pixels(pairs, lambda pair: 2 * file_pixels(pair[0]), params.optimum.batch_size):
        failed += _optimise_and_write(chunk, params, args, size, options, policy)
    print(
        f"wrote the optimum of {len(pairs) - failed} of {len(pairs)} pair(s) to {args.out}", file=sys.stderr
    )
    return 1 if failed else 0


def _check_small(path: Path, shape: tuple[int, ...], start: str, size: tuple[int, int] | None) -> None:
    """A DataError naming ``path`` if its image is too small for the optimum: under
    :data:`msdepth.optimum.solver.MIN_LEVEL_SIDE` px a side, where it runs at the image's own size
    (no working ``size``) or the cost start matches there."""
    from msdepth.optimum.solver import MIN_LEVEL_SIDE

    height, width = shape[:2]
    if min(height, width) >= MIN_LEVEL_SIDE or (size and start != "cost"):
        return
    remedy = (
        "the cost start matches at the image's own size" if start == "cost" else "give --height and --width"
    )
    raise DataError(
        f"{path}: {width}x{height} px is below the optimum's {MIN_LEVEL_SIDE} px a side ({remedy})"
    )


def _fail(exc: Exception) -> int:
    print(f"error: {' '.join(str(exc).splitlines())}", file=sys.stderr)
    return 1


def _naming(path: Path, exc: Exception) -> Exception:
    """``exc`` if its message starts with ``path``, else an MsdepthError naming ``path`` first."""
    return exc if str(exc).startswith(str(path)) else MsdepthError(f"{path}: {exc}")


def _optimise_and_write(
    chunk: list[tuple[Path, Path, Path]],
    params: Params,
    args: argparse.Namespace,
    size: tuple[int, int] | None,
    options: PredictOptions,
    policy: OutputPolicy,
) -> int:
    """Read, optimise and write one batch of pairs; the number that failed (each named on stderr)."""
    from msdepth.cli.predict import output_paths, save_outputs
    from msdepth.data.imagefile import MAX_IMAGE_PIXELS
    from msdepth.data.kitti import read_image
    from msdepth.data.pairs import check_same_size
    from msdepth.geometry.depth import pixel_disparity
    from msdepth.optimum.cost_volume import check_volume_size
    from msdepth.optimum.solver import optimum_disparities
    from msdepth.optimum.starts import capped_size

    failed, good = 0, []
    # Without a working size the optimum runs at the image's own, so that is bounded as a working size is.
    limit = MAX_IMAGE_PIXELS if size else MAX_OPTIMUM_SIDE**2
    for left_path, right_path, stem in chunk:
        try:
            left, right = read_image(left_path, limit), read_image(right_path, limit)
            check_same_size(left_path, left.shape, right_path, right.shape, "right image")
            _check_small(left_path, left.shape, params.optimum.start, size)
            if params.optimum.start == "cost":
                check_volume_size(*capped_size(left.shape[:2], params.optimum.max_width))
            good.append((left_path, stem, left, right))
        except PixelLimitError as exc:
            failed += _fail(
                MsdepthError(f"{exc}, the optimum's at an image's own size (give --height, --width)")
            )
        except DataError as exc:
            failed += _fail(_naming(left_path, exc))
    if not good:
        return failed
    pairs = [(left, right) for _, _, left, right in good]
    disps = optimum_disparities(pairs, params, args.variant, size=size, progress=not args.quiet)
    for (left_path, stem, left, _), disp in zip(good, disps, strict=True):
        try:
            target = _output_stem(Path(args.out), stem, args.variant)
            policy.claim(list(output_paths(target, options).values()), left_path)
            shared = args.colorbar or args.vmax is not None  # the PNG drawn below, on the shared scale
            save_outputs(
                target, left, disp, dataclasses.replace(options, disp_format="npy") if shared else options
            )
            if shared:
                disp_px = pixel_disparity(disp, *left.shape[:2])
                _shared_colours(
                    Path(args.out), (left_path, stem), args, disp_px, policy, list(params.appearance)
                )
        except (MsdepthError, OSError) as exc:
            failed += _fail(_naming(left_path, exc))
    return failed


def _shared_colours(
    out: Path,
    pair: tuple[Path, Path],
    args: argparse.Namespace,
    disp_px: np.ndarray,
    policy: OutputPolicy,
    variants: list[str],
) -> None:
    """Draw the disparity PNG of ``pair`` (its left image and output stem; ``disp_px``, this run's
    variant's) on a shared colour scale: 0 to ``--vmax``; else from the least minimum to the largest
    95th percentile of this map and of the other variants' ``_disp.npy`` of the pair already in
    ``out`` (those of another size are another pair's; ``variants``: every variant's name), each of
    their PNGs redrawn on it. ``--colorbar`` adds the bar."""
    import numpy as np

    from msdepth.cli.predict import color_scale, colorize_disparity
    from msdepth.io import write_png
    from msdepth.readers import read_npy_file

    left_path, stem = pair
    maps = {args.variant: disp_px}
    if args.vmax is None:
        for other in sorted(set(variants) - {args.variant}):
            path = Path(f"{_output_stem(out, stem, other)}_disp.npy")
            if path.is_file():
                found = read_npy_file(path, "disparity")
                if found.shape == disp_px.shape and np.isfinite(found).all():
                    maps[other] = found
        lows, highs = zip(*(color_scale(d) for d in maps.values()), strict=True)
        scale = (min(lows), max(highs))
    else:
        scale = (0.0, float(args.vmax))
    for variant, disp in maps.items():
        png = Path(f"{_output_stem(out, stem, variant)}_disp.png")
        policy.claim([png], left_path)  # this variant's claimed already, the others' from their run
        write_png(png, colorize_disparity(disp, scale, args.colorbar))
