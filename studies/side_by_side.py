"""Trained models' disparities side by side on chosen evaluation frames: image, GT, each model.

Looking at the predictions before believing a metric: e.g. the default input against a larger
one (each model is predicted at its own input size, with flip post-processing, and shown at the
GT's colour scale: disparity as a fraction of the image width).

Run from the repository root after ``dvc repro`` (and a study that trained the other model)::

    python studies/side_by_side.py --models "64 x 192=models/ssim/seed0/model.pt" \\
        "96 x 320=studies/results/x/work/ssim_seed0/model.pt" \\
        --frames 000003_10 000007_10 000012_10 --out disparity.png
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from msdepth.data.eval_index import read_eval_index
from msdepth.data.kitti import read_image
from msdepth.errors import DataError, OutputError, run_main
from msdepth.evaluation.suites import load_frames
from msdepth.outputs import output_file_policy
from msdepth.reporting.figures import write_figure

INDEX = Path("data/index")


def figure(models: dict[str, Path], names: list[str], out: Path) -> None:
    """Write the figure: one row per frame (image, GT disparity, one column per model)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from msdepth.evaluation.infer import predict_disparities
    from msdepth.training.train import load_model

    index = read_eval_index(INDEX / "eval_frames.csv")
    by_name = {f.name: (f, Path(left)) for f, left in zip(load_frames(index), index["left"], strict=True)}
    missing = [n for n in names if n not in by_name]
    if missing:
        raise DataError(f"{INDEX / 'eval_frames.csv'}: no evaluation frame(s) {missing}")
    frames, images = zip(*(by_name[n] for n in names), strict=True)
    predictions = {}
    for label, path in models.items():
        model, meta = load_model(path)
        predictions[label] = predict_disparities(
            model, list(images), meta["height"], meta["width"], True, progress=False
        )
    fig, axes = plt.subplots(len(names), 2 + len(models), figsize=(4 * (2 + len(models)), 2.3 * len(names)))
    axes = np.atleast_2d(axes)
    for row, (frame, image) in enumerate(zip(frames, images, strict=True)):
        depth = np.maximum(frame.gt_depth, 1e-3)
        gt = np.where(frame.gt_depth > 0, frame.focal * frame.baseline / depth / frame.shape[1], np.nan)
        vmax = float(np.nanpercentile(gt, 99)) if np.isfinite(gt).any() else 0.3
        axes[row][0].imshow(read_image(image))
        axes[row][0].set_title(frame.name)
        axes[row][1].imshow(gt, cmap="magma", vmin=0, vmax=vmax)
        axes[row][1].set_title("GT disparity")
        for col, (label, disp) in enumerate(predictions.items(), start=2):
            axes[row][col].imshow(disp[row], cmap="magma", vmin=0, vmax=vmax)
            axes[row][col].set_title(label)
    for ax in axes.flat:
        ax.axis("off")
    fig.tight_layout()
    write_figure(out, fig, dpi=80)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """Predict the frames with every model and write the figure to ``--out``."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--models", nargs="+", required=True, metavar="LABEL=PATH")
    ap.add_argument("--frames", nargs="+", required=True, help="evaluation frame names, e.g. 000003_10")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    models = {}
    for item in args.models:
        label, sep, path = item.rpartition("=")
        if not sep or not label:
            ap.error(f"--models: expected LABEL=PATH, got {item!r}")
        models[label] = Path(path)
    try:
        output_file_policy(args.out, "side-by-side").claim([args.out], INDEX)  # before any model loads
        figure(models, args.frames, args.out)
    except (DataError, OutputError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/side_by_side.py", main))
