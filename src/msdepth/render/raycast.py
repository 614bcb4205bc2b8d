"""Ray casting: the pinhole camera, projecting points, and first hits of rays on the scene."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from msdepth.data.kitti import WIDTH_TO_FOCAL
from msdepth.render.scene import Prim, Scene

_NEAR = 0.05  # m; hits closer than this are ignored


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics plus per-pixel ray directions (world frame, camera-z component 1)."""

    f: float
    cx: float
    cy: float
    height: int
    width: int
    dirs: np.ndarray  # (H, W, 3) float32; t along these is the camera-frame depth
    unit: np.ndarray  # (H, W, 3) float32 normalised


def camera(height: int, width: int, rot: np.ndarray) -> Camera:
    f = focal_for_width(width)
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    d_cam = np.stack([(u - cx) / f, (v - cy) / f, np.ones_like(u)], axis=-1)
    dirs = d_cam @ rot.T
    unit = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
    return Camera(f, cx, cy, height, width, dirs.astype(np.float32), unit.astype(np.float32))


def focal_for_width(width: int) -> float:
    """The synthetic camera's focal length: KITTI's (1242 px wide) scaled to ``width``."""
    return WIDTH_TO_FOCAL[1242] * width / 1242.0


def project(
    points: np.ndarray, rot: np.ndarray, origin: np.ndarray, cam: Camera
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel coordinates (u, v) and camera depth of world points."""
    pc = (points - origin) @ rot  # = R^T (p - o) for each row
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return cam.f * pc[:, 0] / z + cam.cx, cam.f * pc[:, 1] / z + cam.cy, z


def _window(prim: Prim, rot: np.ndarray, origin: np.ndarray, cam: Camera) -> tuple[slice, slice] | None:
    """The pixel rectangle that can see ``prim`` (its projected bounding box), or None."""
    u, v, z = project(prim.corners, rot, origin, cam)
    if (z <= _NEAR).all():
        return None
    if (z <= _NEAR).any():  # straddles the image plane: projected corners do not bound it
        return slice(0, cam.height), slice(0, cam.width)
    u0, u1 = max(int(np.floor(u.min())), 0), min(int(np.ceil(u.max())) + 1, cam.width)
    v0, v1 = max(int(np.floor(v.min())), 0), min(int(np.ceil(v.max())) + 1, cam.height)
    if u0 >= u1 or v0 >= v1:
        return None
    return slice(v0, v1), slice(u0, u1)


def _prim_hits(prim: Prim, origin: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Entry depth (inf = miss) and entry plane index of rays ``origin + t d`` into ``prim``."""
    shape = d.shape[:-1]
    t_in = np.full(shape, -np.inf, np.float32)
    t_out = np.full(shape, np.inf, np.float32)
    plane = np.zeros(shape, np.int8)
    with np.errstate(divide="ignore", invalid="ignore"):
        for i, (n, c) in enumerate(zip(prim.normals, prim.offsets, strict=True)):
            # Skip zero components: most planes are axis-aligned, so this is one multiply.
            denom = None
            for a in range(3):
                if n[a] != 0:
                    term = d[..., a] * n[a]
                    denom = term if denom is None else denom + term
            t = np.float32(c - float(n @ origin)) / denom
            entering = denom < 0
            better = entering & (t > t_in)
            t_in = np.where(better, t, t_in)
            plane[better] = i
            t_out = np.minimum(t_out, np.where(entering, np.inf, t))
    hit = (t_in < t_out) & (t_in > _NEAR)
    return np.where(hit, t_in, np.inf), plane


def _ground_hits(scene: Scene, dirs: np.ndarray, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ray length to the ground plane (inf = none) and face id (0 = ground, -1 = none) of rays
    ``origin + t dirs`` (dirs (..., 3), y down): where tracing starts before the primitives."""
    shape = dirs.shape[:-1]
    depth = np.full(shape, np.inf, np.float32)
    face = np.full(shape, -1, np.int32)
    dy = dirs[..., 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.float32(scene.cam_height - origin[1]) / dy
    ground = (dy > 1e-6) & (t > _NEAR)
    depth[ground] = t[ground]
    face[ground] = 0
    return depth, face


# The rays that can reach a primitive: a window (rows, columns) of a grid of rays, or None.
WindowFn = Callable[[Prim], "tuple[slice, slice] | None"]


def first_hits(
    scene: Scene, dirs: np.ndarray, origin: np.ndarray, window: WindowFn
) -> tuple[np.ndarray, np.ndarray]:
    """Ray length (inf = nothing) and face id (-1 = none) of the first hit of every ray
    ``origin + t dirs`` (dirs (H, W, 3)): the ground plane, then each primitive, cast only along
    the rays that ``window`` says can reach it (the camera's pixels or the LiDAR's beams)."""
    depth, face = _ground_hits(scene, dirs, origin)
    for prim in scene.prims:
        win = window(prim)
        if win is None:
            continue
        t, plane = _prim_hits(prim, origin, dirs[win])
        closer = t < depth[win]
        depth[win] = np.where(closer, t, depth[win])
        face[win] = np.where(closer, plane.astype(np.int32) + prim.face0, face[win])
    return depth, face


def trace(scene: Scene, cam: Camera, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth (inf where nothing is hit) and face id (-1 = sky) of the first hit for every pixel."""
    return first_hits(scene, cam.dirs, origin, lambda prim: _window(prim, scene.rot, origin, cam))
