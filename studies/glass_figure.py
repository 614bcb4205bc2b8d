"""A windshield before and after the dielectric glass model: image, GT and the loss's optimum.

Reads two dumps of ``studies/glass_check.py`` (old and new renderer), picks the evaluation frame
with the most windshield pixels, runs the optimum (:mod:`msdepth.optimum.solver`, SSIM, smoothness 10)
on both, crops around the windshield and writes a figure and the windshield's abs_rel::

    python studies/glass_figure.py /tmp/before /tmp/after studies/results/glass/windshield.png
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from msdepth.config.params import params_from_dict, read_params_file  # noqa: E402
from msdepth.data.kitti import CLASS_BITS  # noqa: E402
from msdepth.errors import run_main
from msdepth.optimum.solver import optimum_disparities  # noqa: E402
from msdepth.outputs import claim_output_file  # noqa: E402
from msdepth.reporting.figures import write_figure  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    """Command line: BEFORE_DIR AFTER_DIR OUT_PNG."""
    before, after, out = (Path(a) for a in (sys.argv[1:] if argv is None else argv)[:3])
    if not claim_output_file(out, "glass-figure", before):  # before the optimum runs
        return 1
    params = params_from_dict(read_params_file(ROOT / "params.yaml"))
    files = sorted(before.glob("1_*.npz"))  # evaluation frames
    counts = [int((np.load(f)["class_map"] & CLASS_BITS["windshield"]).astype(bool).sum()) for f in files]
    name = files[int(np.argmax(counts))].name
    a, b = np.load(before / name), np.load(after / name)
    mask = (a["class_map"] & CLASS_BITS["windshield"]) > 0
    h, w = mask.shape
    disps = optimum_disparities(
        [(a["left"], a["right"]), (b["left"], b["right"])], params, "ssim", 10.0, progress=False
    )
    disps = [cv2.resize(d, (w, h), interpolation=cv2.INTER_LINEAR) * w for d in disps]  # px at render size
    gt = a["disp"]
    valid = mask & (gt > 0)
    errs = [float(np.mean(np.abs(gt[valid] / d[valid] - 1))) for d in disps]  # depth abs_rel = |d_gt/d - 1|
    ys, xs = np.nonzero(mask)
    y0, y1 = max(ys.min() - 15, 0), min(ys.max() + 15, h)
    x0, x1 = max(xs.min() - 40, 0), min(xs.max() + 40, w)
    crop = np.s_[y0:y1, x0:x1]
    vmax = float(np.percentile(gt[crop], 99))
    fig, ax = plt.subplots(2, 3, figsize=(11, 5))
    for row, (img, d, err, label) in enumerate(
        zip((a["left"], b["left"]), disps, errs, ("F0 U(0.25,0.5)", "n U(1.48,1.53)"), strict=True)
    ):
        ax[row, 0].imshow(img[crop])
        ax[row, 0].set_title(f"{label}: image")
        ax[row, 1].imshow(gt[crop], vmin=0, vmax=vmax, cmap="magma")
        ax[row, 1].contour(mask[crop], levels=[0.5], colors="cyan", linewidths=0.8)
        ax[row, 1].set_title("GT disparity (windshield outlined)")
        ax[row, 2].imshow(d[crop], vmin=0, vmax=vmax, cmap="magma")
        ax[row, 2].set_title(f"SSIM optimum, w=10: windshield abs_rel {err:.3f}")
    for x in ax.flat:
        x.axis("off")
    fig.suptitle(f"evaluation frame {name[2:8]}, seed {params.data.synthetic.seed}")
    fig.tight_layout()
    write_figure(out, fig, dpi=110)
    plt.close(fig)
    print(
        f"frame {name}: windshield pixels {int(mask.sum())}; "
        f"abs_rel before {errs[0]:.3f}, after {errs[1]:.3f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/glass_figure.py", main))
