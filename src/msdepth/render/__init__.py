"""The synthetic set's renderer: a procedural street-scene stereo set, written in KITTI's own
on-disk formats.

Every frame is an independent random street (camera pose, facades, cars, poles and signs, shop
windows, sky), ray cast with numpy over all pixels of a rectified pinhole stereo pair with
KITTI's baseline (0.54 m) and KITTI's focal length scaled to the render width. Ground truth is
the exact depth of the first surface hit in the left view (glass counts as the surface, as with
KITTI's car CAD models), stored as disparity.

Glass and signs break the photometric assumption the way real ones do: glass shows a dark
interior at another depth mixed (Fresnel weight) with a reflection of a procedural environment
looked up along the reflected ray, plus a sun highlight; both depend on the viewpoint, so the two
views disagree there beyond what the disparity explains. Signs are diffuse pictograms with a
strong view-dependent gloss.

Output layout under ``root`` (see :func:`generate`): ``raw/`` as KITTI raw data (training pairs,
``train_files.txt``), ``kitti2015/training/`` as the KITTI 2015 stereo benchmark (evaluation
frames with ``disp_occ_0``, ``disp_noc_0``, ``obj_map``, and ``class_map``: the exact pixels of
every ROI class, which KITTI does not have), ``rois.csv`` and ``synthetic.json`` (which marks
the tree as the renderer's own: :mod:`msdepth.data.owners`). The same evaluation frames also form
a raw drive with a simulated Velodyne scan per frame (:mod:`.velodyne_sim`), listed in
``eigen_test_files.txt``: the Eigen split's layout, for the raw-LiDAR evaluation.

Modules, in the order a frame passes through them: :mod:`.scene` (materials, primitives, the
data model), :mod:`.street` and :mod:`.cars` (drawing a random scene), :mod:`.raycast` (camera,
projection, first hits), :mod:`.shading` (a material's look, a table from material to shader),
:mod:`.velodyne_sim` (the simulated LiDAR), :mod:`.frame` (one stereo frame with its ground
truth) and :mod:`.kitti_tree` (writing the KITTI layout; :func:`generate`).
"""

from msdepth.render.frame import (
    EVAL,
    TRAIN,
    Frame,
    frame_rng,
    glass_pixels,
    non_occluded,
    render_frame,
)
from msdepth.render.kitti_tree import (
    DATES,
    EIGEN_TEST_FILES,
    EVAL_DATE,
    EVAL_DRIVE,
    EVAL_GT_NOC,
    EVAL_GT_OCC,
    calib_text,
    eval_drive,
    generate,
    train_drive,
    within_range,
)
from msdepth.render.raycast import focal_for_width

__all__ = [
    "DATES",
    "EIGEN_TEST_FILES",
    "EVAL",
    "EVAL_DATE",
    "EVAL_DRIVE",
    "EVAL_GT_NOC",
    "EVAL_GT_OCC",
    "TRAIN",
    "Frame",
    "calib_text",
    "eval_drive",
    "focal_for_width",
    "frame_rng",
    "generate",
    "glass_pixels",
    "non_occluded",
    "render_frame",
    "train_drive",
    "within_range",
]
