"""Stage ``photometry``: how the evaluation frames look to a photometric loss, beside real pairs."""

from __future__ import annotations

import sys

from msdepth.config.params import Params
from msdepth.data.eval_index import read_eval_index
from msdepth.evaluation.photometry import photometry_report, read_reference
from msdepth.io import atomic_path, write_json, write_text
from msdepth.pipeline.paths import (
    EVAL_FRAMES,
    PHOTOMETRY_FRAMES,
    PHOTOMETRY_SUMMARY,
    PHOTOMETRY_TABLE,
    run_stage,
)
from msdepth.render.kitti_tree import eval_pairs


def photometry(params: Params) -> None:
    """The evaluation frames' GT-warp residual, brightness gap, grey level, noise, gradient energy
    and SSIM at the GT disparity (:mod:`msdepth.evaluation.photometry`), beside the real pairs of
    ``photometry.reference`` and their ratio to them. On the synthetic set the same frames are also
    rendered without the camera (``data.synthetic.camera``), so the table shows what it changes.
    """
    synthetic = params.data.source == "synthetic"
    cfg = params.data.synthetic
    ideal = eval_pairs(cfg, params.data.gt) if synthetic and cfg.camera.enabled else None
    reference = read_reference(params.photometry.reference) if params.photometry.reference else None
    label = "rendered" if synthetic else "evaluation"
    summary, table, frames = photometry_report(read_eval_index(EVAL_FRAMES), reference, ideal, label)
    write_json(PHOTOMETRY_SUMMARY, summary)
    note = f'Measured at {summary["width"]} px wide (grey levels 0-255; docs/design.md "The camera").\n\n'
    write_text(PHOTOMETRY_TABLE, note + table)
    with atomic_path(PHOTOMETRY_FRAMES, suffix=".csv") as tmp:
        frames.to_csv(tmp, index=False, float_format="%.6g")


if __name__ == "__main__":
    sys.exit(run_stage(photometry, *sys.argv[1:]))
