"""Rendering one stereo frame with its ground truth: disparity, occlusion, objects, ROI boxes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msdepth.config.params import CameraConfig
from msdepth.data.kitti import CLASS_BITS, KITTI_BASELINE
from msdepth.render.cars import CAR_COUNT, CAR_DEPTH, CarRanges
from msdepth.render.raycast import Camera, camera, project, trace
from msdepth.render.scene import GLASS, Scene
from msdepth.render.sensor import record
from msdepth.render.shading import shade_view
from msdepth.render.street import build_scene
from msdepth.render.velodyne_sim import Scan, scan_rng, simulate

# Seed-stream tags (render_frame's split): training frames, evaluation frames and training
# sequences (one scene per sequence, sequence_frame) never share a seed.
TRAIN, EVAL, SEQUENCE = 0, 1, 2
SEQUENCE_STEP = 0.8  # m the rig moves forward between frames of a sequence (KITTI: ~1 m at 10 Hz)
_NOC_TOLERANCE = 0.5  # px; left/right disparity agreement for a pixel to count as non-occluded


@dataclass
class Frame:
    """One rendered stereo frame with its ground truth (left view unless stated)."""

    left: np.ndarray  # uint8 RGB (H, W, 3)
    right: np.ndarray
    disp: np.ndarray  # float32 px, 0 = sky (no surface)
    disp_right: np.ndarray  # right-view disparity, used for the occlusion mask
    noc: np.ndarray  # bool: valid and visible in the right view
    obj_map: np.ndarray  # uint8 car instance ids, 0 = background
    class_map: np.ndarray  # uint8 bits of kitti.CLASS_BITS: the exact pixels of every ROI class
    rois: list[tuple[str, int, int, int, int]]  # (class, x0, y0, x1, y1), x1/y1 exclusive
    rotation: np.ndarray  # world-from-camera rotation (world: x right, y down, z forward)
    cam_height: float  # m above the ground plane y = cam_height
    focal: float  # px; principal point at the image centre, baseline KITTI_BASELINE
    scan: Scan | None = None  # the simulated Velodyne's, when rendered with lidar=True


def frame_rng(seed: int, split: int, index: int) -> np.random.Generator:
    """The generator of one frame: independent streams for every (seed, split, index)."""
    return np.random.default_rng([seed, split, index])


def non_occluded(disp: np.ndarray, disp_right: np.ndarray, tolerance: float = _NOC_TOLERANCE) -> np.ndarray:
    """Pixels with a left disparity whose match ``x - d`` lies in the right image and shows the same surface.

    The right view's disparity at the (sub-pixel) match, bracketed by its two neighbours, must
    agree with the left one; an occluder in front would have a larger disparity there.
    """
    h, w = disp.shape
    xr = np.arange(w, dtype=np.float32)[None, :] - disp
    inside = (disp > 0) & (xr >= 0) & (xr <= w - 1)
    x0 = np.clip(np.floor(xr), 0, w - 1).astype(np.int64)
    x1 = np.minimum(x0 + 1, w - 1)
    rows = np.arange(h)[:, None]
    r0, r1 = disp_right[rows, x0], disp_right[rows, x1]
    lo, hi = np.minimum(r0, r1) - tolerance, np.maximum(r0, r1) + tolerance
    return inside & (disp >= lo) & (disp <= hi)


def _rois(
    scene: Scene, cam: Camera, face: np.ndarray, origin: np.ndarray
) -> list[tuple[str, int, int, int, int]]:
    """Boxes of the scene's ROIs in the left view (camera at ``origin``), dropping tiny and mostly
    hidden ones."""
    boxes = []
    for roi in scene.rois:
        u, v, z = project(roi.corners, scene.rot, origin, cam)
        if (z <= 0.1).any():
            continue
        # Pixel j covers [j - 0.5, j + 0.5): the box spans every pixel the projection touches.
        x0, x1 = max(int(np.floor(u.min() + 0.5)), 0), min(int(np.floor(u.max() + 0.5)) + 1, cam.width)
        y0, y1 = max(int(np.floor(v.min() + 0.5)), 0), min(int(np.floor(v.max() + 0.5)) + 1, cam.height)
        if x1 - x0 < 6 or y1 - y0 < 6:
            continue
        if np.isin(face[y0:y1, x0:x1], roi.faces).mean() < 0.5:
            continue
        boxes.append((roi.cls, x0, y0, x1, y1))
    return boxes


def _class_map(scene: Scene, face: np.ndarray) -> np.ndarray:
    """Per pixel of the left view, the bits of the ROI classes whose faces it shows."""
    out = np.zeros(face.shape, np.uint8)
    for cls, bit in CLASS_BITS.items():
        faces = [roi.faces for roi in scene.rois if roi.cls == cls]
        if faces:
            out[np.isin(face, np.concatenate(faces))] |= np.uint8(bit)
    return out


def render_frame(
    seed: int,
    split: int,
    index: int,
    height: int,
    width: int,
    lidar: bool = False,
    cars: CarRanges = (CAR_COUNT, CAR_DEPTH),
    sensor: CameraConfig | None = None,
) -> Frame:
    """Render frame ``index`` of ``split`` (0 = training, 1 = evaluation) deterministically.

    ``lidar``: also scan the scene with the simulated Velodyne (``Frame.scan``); the scan has its
    own generator, so everything else is the same either way. ``cars``: the scene's car count and
    depth ranges (:func:`~msdepth.render.cars.add_cars`). ``sensor``: the photometric camera the
    views pass through (:mod:`msdepth.render.sensor`); None or disabled: the ideal views.
    """
    rng = frame_rng(seed, split, index)
    scene = build_scene(rng, *cars)
    frame = _view_scene(scene, height, width, 0.0, rng, sensor)
    if lidar:
        frame.scan = simulate(scene, frame.focal, width, scan_rng(seed, split, index))
    return frame


def sequence_frame(
    seed: int,
    run: tuple[int, int],
    position: int,
    height: int,
    width: int,
    step: float = SEQUENCE_STEP,
    cars: CarRanges = (CAR_COUNT, CAR_DEPTH),
    sensor: CameraConfig | None = None,
) -> Frame:
    """Frame ``position`` (0, 1, ...) of the training sequence ``run`` (drive, sequence in the
    drive): one static scene, the rig moved ``position * step`` metres along its optical axis, its
    own sensor noise per frame (:func:`sequence_pose` is the left camera's pose); ``sensor`` as in
    :func:`render_frame`."""
    scene = build_scene(np.random.default_rng([seed, SEQUENCE, *run]), *cars)
    noise = np.random.default_rng([seed, SEQUENCE, *run, position + 1])  # + 1: never the scene's seed
    return _view_scene(scene, height, width, position * step, noise, sensor)


def sequence_pose(rotation: np.ndarray, forward: float) -> np.ndarray:
    """The (4, 4) camera-to-world pose of the left camera ``forward`` metres along its optical axis
    (world of the scene: x right, y down, z forward; the first frame's camera at the origin)."""
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = _camera_origin(rotation, 0.0, forward)
    return pose


def _camera_origin(rotation: np.ndarray, offset: float, forward: float) -> np.ndarray:
    """The centre of the rig's camera ``offset`` metres right of the left one (0: the left camera,
    the baseline: the right), the rig ``forward`` metres along its optical axis, in world coordinates."""
    return rotation @ np.array([offset, 0.0, forward])


def _ideal_views(views: list[np.ndarray], rng: np.random.Generator) -> list[np.ndarray]:
    """The views of a rig without a camera model: a 1.5 % gain jitter and a little noise per view
    (the renderer before :mod:`msdepth.render.sensor`; kept so its bytes stay reproducible)."""
    images = []
    for view in views:
        gain = rng.uniform(0.985, 1.015)
        noisy = view * gain + rng.standard_normal(view.shape, dtype=np.float32) * np.float32(0.008)
        images.append((np.clip(noisy, 0, 1) * 255 + 0.5).astype(np.uint8))
    return images


def _view_scene(
    scene: Scene,
    height: int,
    width: int,
    forward: float,
    rng: np.random.Generator,
    sensor: CameraConfig | None = None,
) -> Frame:
    """The stereo frame of ``scene`` seen by the rig ``forward`` metres along its optical axis,
    recorded by ``sensor`` (None or disabled: :func:`_ideal_views`) with draws from ``rng``; no
    LiDAR scan."""
    cam = camera(height, width, scene.rot)
    f = cam.f
    views, depths, faces = [], [], []
    for offset in (0.0, KITTI_BASELINE):
        origin = _camera_origin(scene.rot, offset, forward)
        depth, face = trace(scene, cam, origin)
        views.append(shade_view(scene, cam, origin, depth, face))
        depths.append(depth)
        faces.append(face)
    if sensor is not None and sensor.enabled:
        images = record(views[0], views[1], sensor, rng)
    else:
        images = _ideal_views(views, rng)
    with np.errstate(divide="ignore"):
        disp, disp_right = (
            np.where(np.isfinite(z), f * KITTI_BASELINE / z, 0).astype(np.float32) for z in depths
        )
    inst = scene.arrays["inst"][np.maximum(faces[0], 0)] * (faces[0] >= 0)
    present = np.unique(inst[inst > 0])
    lookup = np.zeros(int(inst.max()) + 1, np.uint8)
    lookup[present] = np.arange(1, present.size + 1)  # renumber visible cars 1..n
    return Frame(
        left=images[0],
        right=images[1],
        disp=disp,
        disp_right=disp_right,
        noc=non_occluded(disp, disp_right),
        obj_map=lookup[inst],
        class_map=_class_map(scene, faces[0]),
        rois=_rois(scene, cam, faces[0], scene.rot @ np.array([0.0, 0.0, forward])),
        rotation=scene.rot,
        cam_height=scene.cam_height,
        focal=f,
    )


def glass_pixels(seed: int, split: int, index: int, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Boolean (H, W) masks of the pixels whose first surface is glass, in the left and right view
    of frame ``index`` of ``split``: the only pixels the glass model may change (docs/glass.md)."""
    scene = build_scene(frame_rng(seed, split, index))
    cam = camera(height, width, scene.rot)
    masks = []
    for offset in (0.0, KITTI_BASELINE):
        _, face = trace(scene, cam, scene.rot @ np.array([offset, 0.0, 0.0]))
        masks.append((face >= 0) & (scene.arrays["mat"][np.maximum(face, 0)] == GLASS))
    return masks[0], masks[1]
