"""Command line: ``msdepth predict``, ``optimum``, ``export-onnx``, ``export-folder``,
``experiments`` and ``photometry`` (also ``python -m msdepth``)."""

from __future__ import annotations

import argparse
import sys
from typing import Callable, Sequence

from msdepth.cli.experiments import experiments_command
from msdepth.cli.optimum import optimum_command
from msdepth.cli.options import camera_options
from msdepth.cli.photometry import photometry_command
from msdepth.errors import MsdepthError, unexpected_error
from msdepth.outputs import settle_outputs

# A subcommand is a function that adds its parser with ``add_parser`` (the subparsers' own method:
# name, help, description) and sets ``run``, the function that runs it; _COMMANDS lists them in
# the order of ``msdepth --help``.
AddParser = Callable[..., argparse.ArgumentParser]


def _predict_command(add_parser: AddParser) -> None:
    p = add_parser(
        "predict",
        help="disparity, metric depth and point clouds for images, folders or videos",
        description="Predict every image of INPUT (an image, a folder searched recursively, or a video "
        "file, one output per frame) and write its outputs under --out, named after the input.",
    )
    p.add_argument("input", metavar="INPUT", help="image, folder of images or video file")
    p.add_argument("--model", required=True, help="trained model file, e.g. models/msssim/seed0/model.pt")
    p.add_argument("--out", required=True, help="output folder")
    # Options left at None take PredictOptions' defaults (kept there, so --help need not import torch).
    p.add_argument("--height", type=int, help="network input height (default: the model's training size)")
    p.add_argument("--width", type=int, help="network input width (default: the model's training size)")
    p.add_argument(
        "--no-post-process",
        dest="post_process",
        action="store_false",
        help="skip Monodepth's flip post-processing (twice as fast, slightly worse near edges)",
    )
    camera_options(p)
    _output_options(p)
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), help="default: auto (CUDA if available)")
    p.add_argument(
        "--batch-size",
        type=int,
        help="at most this many frames per network batch, fewer once they hold 32 megapixels (default: 8)",
    )
    p.add_argument(
        "--max-megapixels",
        type=float,
        help="refuse larger images before decoding them (default: 120, a 108-megapixel photo fits)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=_predict)


def _output_options(p: argparse.ArgumentParser) -> None:
    """predict's outputs: depth range, file formats, point cloud and colour bar."""
    p.add_argument(
        "--max-depth",
        type=float,
        help="depths beyond this (m) are invalid (0) in the depth outputs and dropped from point clouds "
        "(default: 80)",
    )
    p.add_argument(
        "--disp-format",
        choices=("png", "npy", "both", "none"),
        help="disparity outputs: colour PNG and/or .npy in px (default: both)",
    )
    p.add_argument(
        "--depth-format",
        choices=("png", "npy", "both", "none"),
        help="depth outputs: 16-bit PNG in mm and/or .npy in m (default: png)",
    )
    p.add_argument(
        "--ply", choices=("none", "binary", "ascii"), help="write a coloured point cloud (default: none)"
    )
    p.add_argument(
        "--colorbar", action="store_true", help="add a colour bar (disparity in px) to the disparity PNG"
    )


def _export_onnx_command(add_parser: AddParser) -> None:
    e = add_parser(
        "export-onnx",
        help="export the depth network to ONNX",
        description="Export the network to ONNX. Input 'image': float32 (B, 3, H, W), RGB in [0, 1]; "
        "output 'disparity': float32 (B, 2, H, W), the finest scale, channel 0 = left disparity as a "
        "fraction of the width. Batch, height and width are dynamic unless --static.",
    )
    e.add_argument("--model", required=True, help="trained model file, e.g. models/msssim/seed0/model.pt")
    e.add_argument("--out", required=True, help="ONNX file to write")
    e.add_argument("--height", type=int, help="tracing input height (default: the model's training size)")
    e.add_argument("--width", type=int, help="tracing input width (default: the model's training size)")
    e.add_argument("--opset", type=int, help="ONNX opset, 11 to 20 (default: 17)")
    e.add_argument("--static", action="store_true", help="fix the input to 1 x 3 x height x width")
    e.set_defaults(run=_export_onnx)


def _export_folder_command(add_parser: AddParser) -> None:
    f = add_parser(
        "export-folder",
        help="write a stereo folder (data.source: folder) from the synthetic set",
        description="Write the KITTI-format tree FROM (e.g. the synthetic set in data/synthetic) as a stereo "
        "folder for data.source: folder: left/ and right/ (training and evaluation images), camera.yaml, "
        "eval.txt and the evaluation GT as PFM disparity in gt/. See docs/user-guide.md 'Train and evaluate "
        "on your own stereo camera'.",
    )
    f.add_argument("--from", dest="source", required=True, help="KITTI-format tree, e.g. data/synthetic")
    f.add_argument("--to", dest="out", required=True, help="folder to write (must not exist or be empty)")
    f.set_defaults(run=_export_folder)


_COMMANDS: tuple[Callable[[AddParser], None], ...] = (
    _predict_command,
    _export_onnx_command,
    _export_folder_command,
    optimum_command,
    experiments_command,
    photometry_command,
)


def _build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="msdepth", description="Use a trained msdepth model.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add_command in _COMMANDS:
        add_command(sub.add_parser)
    return parser


def _predict(args: argparse.Namespace) -> int:
    from msdepth.cli.predict import PredictOptions, predict

    names = (
        "height",
        "width",
        "post_process",
        "focal",
        "baseline",
        "cx",
        "cy",
        "max_depth",
        "disp_format",
        "depth_format",
        "ply",
        "colorbar",
        "batch_size",
        "device",
        "max_megapixels",
    )
    given = {name: getattr(args, name) for name in names if getattr(args, name) is not None}
    options = PredictOptions(**given, progress=not args.quiet)
    report = predict(args.input, args.model, args.out, options)
    if report.ignored:
        print(
            f"ignored {len(report.ignored)} file(s) that are not images, e.g. {report.ignored[0]}",
            file=sys.stderr,
        )
    total = report.written + len(report.failed)
    failed = f"; {len(report.failed)} failed (listed above)" if report.failed else ""
    print(f"wrote the outputs of {report.written} of {total} frame(s) to {args.out}{failed}", file=sys.stderr)
    return 1 if report.failed else 0


def _export_onnx(args: argparse.Namespace) -> int:
    from msdepth.cli.onnx_export import export_onnx

    export_onnx(args.model, args.out, args.height, args.width, args.opset, dynamic=not args.static)
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


def _export_folder(args: argparse.Namespace) -> int:
    from msdepth.cli.folder_export import export_folder

    report = export_folder(args.source, args.out)
    print(
        f"wrote {args.out}: {report['train_pairs']} training pairs, {report['eval_frames']} evaluation "
        f"frames with PFM GT, camera {report['focal_px']:g} px at {report['width_px']} px",
        file=sys.stderr,
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (0 ok, 1 error or failed frames, 2 usage)."""
    args = _build_parser().parse_args(argv)
    try:
        return args.run(args)
    except MsdepthError as exc:
        print(f"error: {' '.join(str(exc).splitlines())}", file=sys.stderr)
        return 1
    except OSError as exc:  # a file system failure no check foresaw: still one line naming the path
        print(f"error: {exc.filename or ''}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    except Exception as exc:  # a bug: one line naming the command, the traceback in a log file
        line = unexpected_error(f"msdepth {args.command}", exc, list(argv or sys.argv[1:])[1:])
        print(line, file=sys.stderr)
        return 1
    finally:
        settle_outputs()  # each output manifest lists only the files that were written


if __name__ == "__main__":
    sys.exit(main())
