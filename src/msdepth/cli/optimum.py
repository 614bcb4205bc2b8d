"""``msdepth optimum LEFT RIGHT --variant NAME --out DIR``: the losses' own optimum of any stereo pair.

Kept apart from :mod:`msdepth.optimum.solver` so that building the parser (``msdepth --help``) imports
no torch. Writes, per pair, what ``msdepth predict`` writes for a frame (its own writer,
:func:`msdepth.cli.predict.save_outputs`), named after the variant too, so that both variants'
results of a pair sit side by side in one folder: ``<stem>_<variant>_disp.npy`` (disparity in px at
LEFT's resolution, float32), ``<stem>_<variant>_disp.png`` and ``<stem>_<variant>_depth.npy`` (metres).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from msdepth.cli.options import camera_options
from msdepth.config.params import MAX_OPTIMUM_SIDE, Params, apply_overrides, load_params, params_from_dict
from msdepth.errors import ConfigError, DataError, MsdepthError, PixelLimitError
from msdepth.outputs import OutputPolicy

if TYPE_CHECKING:
    from msdepth.cli.predict import PredictOptions

# Adam steps per level without a params file: the instrument's measured stopping rule
# (docs/optimum.md, "Stopping rule"); params.yaml's 50 fits the pipeline's time budget.
INSTRUMENT_ITERATIONS = 100


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
    o.add_argument("--quiet", action="store_true", help="no progress bar")
    o.set_defaults(run=run)


def _read_params(path: str | None, assignments: list[str]) -> Params:
    """``path`` (or ./params.yaml, or the defaults with ``optimum.iterations``
    :data:`INSTRUMENT_ITERATIONS`) with the ``--set`` assignments, validated: the hardened reader
    and checks of every params file (:func:`msdepth.config.params.load_params`)."""
    source = Path(path) if path else Path("params.yaml")
    if path or source.is_file():
        return load_params(source, assignments)
    return params_from_dict(apply_overrides({"optimum": {"iterations": INSTRUMENT_ITERATIONS}}, assignments))


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
            save_outputs(target, left, disp, options)
        except (MsdepthError, OSError) as exc:
            failed += _fail(_naming(left_path, exc))
    return failed
