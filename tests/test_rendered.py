"""msdepth.evaluation.rendered: the evaluation frames the studies render in memory are the pipeline's."""

from __future__ import annotations

import dataclasses

import numpy as np

from msdepth.config.params import SyntheticConfig
from msdepth.evaluation.rendered import ROI_KEYS, rendered_eval_set
from msdepth.render.kitti_tree import EVAL_GT_OCC, eval_pairs

TINY = SyntheticConfig(eval_frames=2, height=48, width=160)


def test_the_rendered_set_is_the_pipelines_evaluation_frames_through_its_camera() -> None:
    """Through the configured camera, each pair and its GT disparity are the bytes the renderer's own
    evaluation frames have (eval_pairs, occluded GT); with the camera off, the ideal views."""
    for cfg in (TINY, dataclasses.replace(TINY, camera=dataclasses.replace(TINY.camera, enabled=False))):
        got = rendered_eval_set(cfg, 2, cfg.camera)
        for (name, left, right, disp), frame, pair in zip(
            eval_pairs(cfg, EVAL_GT_OCC, cfg.camera), got.frames, got.pairs, strict=True
        ):
            assert frame.name == name and pair[0].tobytes() == left.tobytes()
            assert pair[1].tobytes() == right.tobytes()
            assert np.array_equal(frame.valid, disp > 0)
    assert list(got.rois.columns) == list(ROI_KEYS) and set(got.rois["image"]) <= {f.name for f in got.frames}


def test_no_camera_and_a_disabled_camera_render_the_same_bytes() -> None:
    """``sensor`` None and a disabled camera both give the ideal views."""
    off = dataclasses.replace(TINY.camera, enabled=False)
    a, b = rendered_eval_set(TINY, 1, None), rendered_eval_set(TINY, 1, off)
    assert all(x.tobytes() == y.tobytes() for x, y in zip(a.pairs[0], b.pairs[0], strict=True))
