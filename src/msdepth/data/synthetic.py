"""A procedural street-scene stereo set, written in KITTI's own on-disk formats.

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
every ROI class, which KITTI does not have), ``rois.csv`` and ``synthetic.json``. The same
evaluation frames also form a raw drive with a simulated Velodyne scan per frame
(:mod:`msdepth.data.velodyne_sim`), listed in ``eigen_test_files.txt``: the Eigen split's layout,
for the raw-LiDAR evaluation.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
import shutil
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable

import numpy as np
import pandas as pd

from ..config import SyntheticConfig
from ..io import atomic_path, write_json, write_png, write_text
from .kitti import (
    CLASS_BITS,
    KITTI_BASELINE,
    WIDTH_TO_FOCAL,
    read_raw_calib,
    velodyne_depth,
    write_disparity,
    write_rois,
    write_split,
    write_velodyne,
)

if TYPE_CHECKING:
    from .velodyne_sim import Scan

DATES = ("2011_09_26", "2011_09_28", "2011_09_29", "2011_09_30", "2011_10_03")
# The raw drive holding the evaluation frames with their LiDAR scans: training drives are numbered
# 1..drives, so this one cannot collide with them (generate refuses drives >= EVAL_DRIVE).
EVAL_DATE, EVAL_DRIVE = DATES[0], 9000
EIGEN_TEST_FILES = "eigen_test_files.txt"
EVAL_GT_OCC = "disp_occ_0"
EVAL_GT_NOC = "disp_noc_0"
_TRAIN, _EVAL = 0, 1  # seed-stream tags: training and evaluation frames never share a seed
_NEAR = 0.05  # m; hits closer than this are ignored
_NOC_TOLERANCE = 0.5  # px; left/right disparity agreement for a pixel to count as non-occluded

# Material ids.
ROAD, WALL, FOLIAGE, PAINT, GLASS, TYRE, POLE, SIGN, METAL = range(9)

# A fixed tile of value noise, sampled with world/surface coordinates (plus a per-frame shift) so
# that both views see the same texture. Its own fixed seed keeps it independent of the frame RNG.
_TILE = np.random.default_rng(0x5EED).random((256, 256), dtype=np.float32)
_TILE_FLAT = _TILE.ravel()
_UP = np.array([0.0, -1.0, 0.0])


# --------------------------------------------------------------------------------------------
# Scene description


@dataclass
class _Roi:
    """An evaluation box: its class, the faces that belong to it, and 3-D points spanning it."""

    cls: str
    faces: np.ndarray
    corners: np.ndarray


@dataclass
class _Prim:
    """A convex polytope ``{p : normals @ p <= offsets}`` whose faces start at ``face0``."""

    normals: np.ndarray
    offsets: np.ndarray
    corners: np.ndarray
    face0: int


@dataclass
class _Scene:
    """Everything one frame needs: camera pose, primitives, per-face attributes, lighting."""

    cam_height: float
    rot: np.ndarray  # world-from-camera rotation (world: x right, y down, z forward)
    sun: np.ndarray  # unit vector towards the sun
    sun_colour: np.ndarray
    ambient: float
    sky_horizon: np.ndarray
    sky_zenith: np.ndarray
    cloud_cover: float
    canopy: float  # how much of the reflected overhead environment is dark structure
    tex_shift: tuple[float, float]  # python floats: numpy float64 scalars would upcast float32 arrays
    road: dict[str, Any]
    prims: list[_Prim] = field(default_factory=list)
    rois: list[_Roi] = field(default_factory=list)
    faces: list[dict[str, Any]] = field(default_factory=list)
    arrays: dict[str, np.ndarray] = field(default_factory=dict)

    def add_face(
        self,
        normal: np.ndarray,
        material: int,
        origin: np.ndarray,
        colour: Iterable[float],
        colour2: Iterable[float] = (0, 0, 0),
        params: Iterable[float] = (),
        instance: int = 0,
    ) -> int:
        """Register one face's shading attributes; returns its global face id."""
        n = np.asarray(normal, float)
        nx, ny, nz = n
        if abs(ny) < 0.9:  # texture axes: u = up x n (horizontal along the face), v = n x u (up)
            norm = np.hypot(nx, nz)
            u = np.array([-nz / norm, 0.0, nx / norm])
            v = np.array([ny * u[2], nz * u[0] - nx * u[2], -ny * u[0]])
        else:
            u, v = np.array([1.0, 0, 0]), np.array([0, 0, 1.0])
        prm = np.zeros(8)
        p = list(params)
        prm[: len(p)] = p
        self.faces.append(
            dict(
                normal=n,
                mat=material,
                org=np.asarray(origin, float),
                uax=u,
                vax=v,
                col=np.asarray(colour, float),
                col2=np.asarray(colour2, float),
                prm=prm,
                inst=instance,
            )
        )
        return len(self.faces) - 1

    def add_polytope(
        self, normals: np.ndarray, offsets: np.ndarray, corners: np.ndarray, face_args: list[dict[str, Any]]
    ) -> list[int]:
        """Add a convex polytope (one face description per plane); returns its face ids."""
        ids = [self.add_face(n, **a) for n, a in zip(normals, face_args, strict=True)]
        self.prims.append(
            _Prim(
                np.asarray(normals, np.float32),
                np.asarray(offsets, np.float64),
                np.asarray(corners, float),
                ids[0],
            )
        )
        return ids

    def finalise(self) -> None:
        """Stack per-face attributes into arrays indexed by face id."""
        for key in ("normal", "mat", "org", "uax", "vax", "col", "col2", "prm", "inst"):
            dtype = np.int32 if key in ("mat", "inst") else np.float32
            self.arrays[key] = np.array([f[key] for f in self.faces], dtype=dtype)


def _box_planes(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Planes (-x, +x, -y, +y, -z, +z) and 8 corners of an axis-aligned box."""
    normals = np.array([[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]], float)
    offsets = np.array([-lo[0], hi[0], -lo[1], hi[1], -lo[2], hi[2]], float)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return normals, offsets, corners


def _yaw_matrix(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _place(
    normals: np.ndarray, offsets: np.ndarray, corners: np.ndarray, rot: np.ndarray, pos: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Move a polytope given in a local frame by rotation ``rot`` and translation ``pos``."""
    n = normals @ rot.T
    return n, offsets + n @ pos, corners @ rot.T + pos


def _camera_rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """World-from-camera rotation: roll about z, then pitch about x, then yaw about y."""
    cy, sy, cp, sp, cr, sr = (
        np.cos(yaw),
        np.sin(yaw),
        np.cos(pitch),
        np.sin(pitch),
        np.cos(roll),
        np.sin(roll),
    )
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return ry @ rx @ rz


def _hsv(h: float, s: float, v: float) -> np.ndarray:
    """An RGB colour from hue/saturation/value in [0, 1]."""
    i = int(h * 6) % 6
    f = h * 6 - int(h * 6)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    return np.array([(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i])


# Adds an axis-aligned box: (lo, hi, face attributes given the face normal) -> face ids.
_BoxFn = Callable[[Iterable[float], Iterable[float], Callable[[np.ndarray], dict[str, Any]]], list[int]]

_CAR_COLOURS = [
    (0.85, 0.85, 0.85),
    (0.6, 0.62, 0.65),
    (0.08, 0.08, 0.09),
    (0.55, 0.06, 0.05),
    (0.08, 0.15, 0.45),
    (0.25, 0.27, 0.3),
    (0.7, 0.7, 0.62),
    (0.1, 0.3, 0.15),
]


def _build_scene(rng: np.random.Generator) -> _Scene:
    """Draw one random street scene (all randomness of the frame's layout comes from ``rng``)."""
    u = rng.uniform
    cam_h = u(1.4, 1.9)
    rot = _camera_rotation(np.radians(u(-4, 4)), np.radians(u(-3, 3)), np.radians(u(-1, 1)))
    sun = np.array([u(-1, 1), -u(0.3, 1.2), u(-0.6, 1.0)])
    warm = u(0, 0.15)
    horizon = _hsv(u(0.52, 0.62), u(0.05, 0.3), u(0.75, 0.95))
    zenith = _hsv(u(0.55, 0.65), u(0.3, 0.7), u(0.5, 0.85))

    # Street cross-section: each side has a facade line (or open land) 3-15 m away.
    sides: dict[int, dict[str, Any]] = {}
    for s in (-1, 1):
        dist = u(3, 15)
        sidewalk = u(1.0, max(1.0, min(4.0, dist - 2.0)))
        sides[s] = dict(built=rng.random() < 0.8, dist=dist, sidewalk=sidewalk, edge=s * (dist - sidewalk))
    left, right = sides[-1]["edge"], sides[1]["edge"]
    lane = u(2.8, 3.6)
    lines = list(np.arange(left + lane, right - 1.0, lane))
    road = dict(
        left=left,
        right=right,
        lines=np.array(lines),
        line_width=u(0.1, 0.16),
        dash=u(2, 4),
        period=u(7, 12),
        phase=u(0, 10),
        asphalt=u(0.22, 0.38),
        pave=_hsv(u(0.05, 0.12), u(0.05, 0.25), u(0.5, 0.7)),
        grass_left=-sides[-1]["dist"] if not sides[-1]["built"] else -1e9,
        grass_right=sides[1]["dist"] if not sides[1]["built"] else 1e9,
    )
    scene = _Scene(
        cam_height=cam_h,
        rot=rot,
        sun=sun / np.linalg.norm(sun),
        sun_colour=(np.array([1.0, 1.0 - warm * 0.5, 1.0 - warm]) * u(0.55, 0.9)).astype(np.float32),
        ambient=u(0.3, 0.5),
        sky_horizon=horizon.astype(np.float32),
        sky_zenith=zenith.astype(np.float32),
        cloud_cover=u(0.0, 0.8),
        canopy=u(0.6, 1.0),
        tex_shift=(u(0, 256), u(0, 256)),
        road=road,
    )
    ground = np.array([0.0, cam_h, 0.0])
    scene.add_face(_UP, ROAD, ground, (0, 0, 0))  # face 0: the ground plane (shaded from `road`)

    def box(lo, hi, faces: Callable[[np.ndarray], dict[str, Any]]) -> list[int]:
        normals, offsets, corners = _box_planes(np.asarray(lo, float), np.asarray(hi, float))
        return scene.add_polytope(normals, offsets, corners, [faces(n) for n in normals])

    for s, side in sides.items():
        if side["built"]:
            _add_facades(scene, rng, s, side["dist"], ground, box)
        else:
            _add_open_side(scene, rng, s, side["dist"], ground, box)
    if rng.random() < 0.45:  # a building closing the street far ahead
        zf, height = u(45, 150), u(8, 30)
        colour = _hsv(u(0, 1), u(0.05, 0.35), u(0.35, 0.8))
        prm = (u(1.6, 3.5), u(2.8, 3.6), u(0.35, 0.65), u(0.4, 0.65), float(rng.random() < 0.3), 3.0, height)
        box(
            (-90, cam_h - height, zf),
            (90, cam_h + 0.1, zf + 12),
            lambda n: dict(
                material=WALL, origin=ground, colour=colour, colour2=(0.1, 0.12, 0.16), params=prm
            ),
        )

    _add_cars(scene, rng, sides, road)
    _add_poles(scene, rng, sides, ground, box)
    scene.finalise()
    return scene


def _add_facades(
    scene: _Scene, rng: np.random.Generator, s: int, dist: float, ground: np.ndarray, box: _BoxFn
) -> None:
    """Building blocks along one side: segments with their own setback, height, colour, windows."""
    u = rng.uniform
    cam_h = scene.cam_height
    z, z_end = u(-10, -3), u(60, 140)
    while z < z_end:
        length = u(6, 25)
        if rng.random() < 0.12:  # an alley: whatever is behind shows through
            z += u(3, 10)
            continue
        d = dist + (u(0, 2.5) if rng.random() < 0.5 else 0.0)
        height = u(4, 22)
        colour = _hsv(u(0, 1), u(0.05, 0.4), u(0.3, 0.85))
        window = _hsv(u(0.5, 0.7), u(0.1, 0.4), u(0.08, 0.3))
        prm = (
            u(1.6, 3.5),
            u(2.8, 3.6),
            u(0.35, 0.65),
            u(0.4, 0.65),
            float(rng.random() < 0.35),
            u(2.8, 4.0),
            height,
        )
        xs = sorted((s * d, s * (d + 12)))
        box(
            (xs[0], cam_h - height, z),
            (xs[1], cam_h + 0.1, z + length),
            lambda n: dict(material=WALL, origin=ground, colour=colour, colour2=window, params=prm),  # noqa: B023 - box() calls it at once
        )
        if 3 < z + length and z < 45 and rng.random() < 0.35:  # shop window at street level
            w_len = u(2, 6)
            z0 = u(max(z, 2), max(z, 2) + max(0.1, length - w_len))
            z1 = min(z0 + w_len, z + length - 0.3)
            top, bottom = cam_h - u(2.2, 2.8), cam_h - u(0.3, 0.6)
            xs = sorted((s * (d - 0.04), s * d))
            tint = _hsv(u(0, 1), u(0.1, 0.5), u(0.1, 0.35))
            glass = dict(material=GLASS, origin=ground, colour=tint, params=(u(0.2, 0.45), u(1.5, 4.0)))
            ids = box((xs[0], top, z0), (xs[1], bottom, z1), lambda n: glass)  # noqa: B023 - box() calls it at once
            front = ids[0] if s > 0 else ids[1]  # the face looking at the street
            x = s * (d - 0.04)
            scene.rois.append(
                _Roi(
                    "glass",
                    np.array([front]),
                    np.array([[x, top, z0], [x, bottom, z0], [x, top, z1], [x, bottom, z1]]),
                )
            )
        z += length


def _add_open_side(
    scene: _Scene, rng: np.random.Generator, s: int, dist: float, ground: np.ndarray, box: _BoxFn
) -> None:
    """No buildings: a hedge along the road and/or a distant tree line across a field."""
    u = rng.uniform
    cam_h = scene.cam_height
    green = _hsv(u(0.22, 0.36), u(0.4, 0.8), u(0.2, 0.5))
    if rng.random() < 0.6:
        xs = sorted((s * dist, s * (dist + u(0.6, 1.5))))
        h = u(0.8, 2.2)
        box(
            (xs[0], cam_h - h, u(-10, -2)),
            (xs[1], cam_h + 0.1, u(30, 120)),
            lambda n: dict(material=FOLIAGE, origin=ground, colour=green),
        )
    if rng.random() < 0.7:
        far = dist + u(10, 50)
        xs = sorted((s * far, s * (far + 8)))
        h = u(5, 15)
        box(
            (xs[0], cam_h - h, u(-20, 10)),
            (xs[1], cam_h + 0.1, u(60, 200)),
            lambda n: dict(material=FOLIAGE, origin=ground, colour=green * u(0.6, 1.0)),
        )


def _add_cars(scene: _Scene, rng: np.random.Generator, sides: dict, road: dict) -> None:
    """0-6 cars (parked at the kerb or in a lane): body, cabin with windshields and side glass, wheels."""
    u = rng.uniform
    cam_h = scene.cam_height
    placed: list[tuple[float, float, float, float]] = []
    lane_centres = np.concatenate([[road["left"]], road["lines"]]) + 0.5 * (
        np.diff(np.concatenate([[road["left"]], road["lines"], [road["right"]]]))
    )
    instance = 0
    for _ in range(int(rng.integers(0, 7))):
        for _attempt in range(20):
            length, width = u(3.8, 4.9), u(1.65, 1.95)
            if rng.random() < 0.5:
                s = int(rng.choice([-1, 1]))
                x = sides[s]["edge"] - s * (width / 2 + u(0.2, 0.5))
                yaw = np.radians(u(-5, 5)) + (np.pi if rng.random() < 0.5 else 0.0)
            else:
                x = float(rng.choice(lane_centres)) + u(-0.4, 0.4)
                yaw = np.radians(u(-4, 4)) + (np.pi if x < -1.5 and rng.random() < 0.7 else 0.0)
            zc = u(4, 40)
            near = zc - length / 2
            if abs(x) < width / 2 + 1.2 and near < 5:
                continue  # nothing sits on top of the camera car
            fp = (x - width / 2 - 0.4, x + width / 2 + 0.4, zc - length / 2 - 0.5, zc + length / 2 + 0.5)
            if any(fp[0] < q[1] and q[0] < fp[1] and fp[2] < q[3] and q[2] < fp[3] for q in placed):
                continue
            placed.append(fp)
            instance += 1
            _add_car(scene, rng, instance, np.array([x, cam_h, zc]), yaw, length, width)
            break


def _add_car(
    scene: _Scene,
    rng: np.random.Generator,
    instance: int,
    pos: np.ndarray,
    yaw: float,
    length: float,
    width: float,
) -> None:
    """One car at ``pos`` (centre on the ground) heading ``yaw``; registers its ROIs."""
    u = rng.uniform
    rot = _yaw_matrix(yaw)
    paint = np.array(_CAR_COLOURS[int(rng.integers(len(_CAR_COLOURS)))]) * u(0.85, 1.1)
    tint = np.array([0.03, 0.035, 0.04]) * u(0.7, 2.0)
    glass_prm = (u(0.25, 0.5), u(0.8, 1.6))  # (Fresnel F0 of tinted glass, interior depth m)
    clear, top = u(0.22, 0.3), u(0.85, 1.05)
    roof = top + u(0.42, 0.58)
    half_l, w2 = length / 2, width / 2 - 0.08  # cabin slightly narrower than the body
    base_front, base_back = half_l * u(0.45, 0.6), -half_l * u(0.55, 0.75)
    roof_front, roof_back = base_front - u(0.6, 1.0), base_back + u(0.3, 0.7)
    car_faces: list[int] = []

    def faces(material: int, extra: tuple = ()) -> dict[str, Any]:
        prm = glass_prm if material == GLASS else extra
        return dict(
            material=material,
            origin=pos,
            colour=tint if material == GLASS else paint,
            params=prm,
            instance=instance,
        )

    # Lower body (paint) with lights on the front/back faces (params[0]: 1 front, 2 back).
    n, c, k = _box_planes(np.array([-width / 2, -top, -half_l]), np.array([width / 2, -clear, half_l]))
    args = [faces(PAINT, (1.0 if nl[2] > 0.5 else 2.0 if nl[2] < -0.5 else 0.0, width / 2)) for nl in n]
    n, c, k = _place(n, c, k, rot, pos)
    body_corners = k
    car_faces += scene.add_polytope(n, c, k, args)

    # Cabin: a prism whose front and back faces are the tilted windshield and rear window.
    def tilted(z_base: float, z_roof: float, sign: float) -> tuple[np.ndarray, float]:
        normal = np.array([0.0, -sign * (z_base - z_roof), sign * (roof - top)])
        normal /= np.linalg.norm(normal)
        return normal, float(normal @ np.array([0.0, -top, z_base]))

    nf, cf = tilted(base_front, roof_front, 1.0)
    nb, cb = tilted(base_back, roof_back, -1.0)
    n = np.array([[0, 1, 0], [0, -1, 0], [1, 0, 0], [-1, 0, 0], nf, nb], float)
    c = np.array([-top + 0.02, roof, w2, w2, cf, cb])
    k = np.array(
        [
            [x, -yy, zz]
            for x in (-w2, w2)
            for yy, zz in ((top, base_front), (roof, roof_front), (top, base_back), (roof, roof_back))
        ]
    )
    mats = [PAINT, PAINT, GLASS, GLASS, GLASS, GLASS]
    args = [faces(m) for m in mats]
    n, c, k = _place(n, c, k, rot, pos)
    ids = scene.add_polytope(n, c, k, args)
    car_faces += ids
    quad = {2: k[[4, 5, 6, 7]], 3: k[[0, 1, 2, 3]], 4: k[[0, 1, 4, 5]], 5: k[[2, 3, 6, 7]]}
    for local, cls in ((2, "glass"), (3, "glass"), (4, "windshield"), (5, "windshield")):
        scene.rois.append(_Roi(cls, np.array([ids[local]]), quad[local]))
    cabin_corners = k

    # Wheels: one dark box per axle, standing on the ground (part of the car's box).
    wheel_corners = []
    for zc in (half_l - u(0.75, 0.95), -half_l + u(0.75, 0.95)):
        r = u(0.3, 0.36)
        n, c, k = _box_planes(
            np.array([-width / 2 + 0.03, -(clear + 0.2), zc - r]), np.array([width / 2 - 0.03, 0.0, zc + r])
        )
        args = [dict(material=TYRE, origin=pos, colour=(0.05, 0.05, 0.055), instance=instance) for _ in n]
        n, c, k = _place(n, c, k, rot, pos)
        car_faces += scene.add_polytope(n, c, k, args)
        wheel_corners.append(k)
    corners = np.concatenate([body_corners, cabin_corners, *wheel_corners])
    scene.rois.append(_Roi("car", np.array(car_faces), corners))


def _add_poles(scene: _Scene, rng: np.random.Generator, sides: dict, ground: np.ndarray, box: _BoxFn) -> None:
    """Poles on the sidewalks, most carrying a sign plate facing (roughly) the camera."""
    u = rng.uniform
    cam_h = scene.cam_height
    for _ in range(int(rng.integers(0, 5))):
        s = int(rng.choice([-1, 1]))
        side = sides[s]
        x = side["edge"] + s * u(0.3, max(0.35, side["sidewalk"] - 0.3))
        z = u(4, 50)
        height, r = u(2.5, 4.2), u(0.04, 0.08)
        grey = np.full(3, u(0.35, 0.6))
        box(
            (x - r, cam_h - height, z - r),
            (x + r, cam_h + 0.1, z + r),
            lambda n: dict(material=POLE, origin=ground, colour=grey),  # noqa: B023 - box() calls it at once
        )
        if rng.random() > 0.75:
            continue
        w, h = u(0.5, 0.9), u(0.45, 0.9)
        yaw = np.radians(u(-30, 30)) + (np.pi if rng.random() < 0.15 else 0.0)
        centre = np.array([x, cam_h - height + h / 2 + u(0, 0.3), z - r - 0.03])
        kind = float(rng.integers(4))
        n, c, k = _box_planes(np.array([-w / 2, -h / 2, -0.015]), np.array([w / 2, h / 2, 0.015]))
        rot = _yaw_matrix(yaw)
        args = [
            dict(material=SIGN, origin=centre, colour=(0, 0, 0), params=(kind, w, h, u(0.6, 1.6)))
            if nl[2] < -0.5
            else dict(material=METAL, origin=centre, colour=grey)
            for nl in n
        ]
        n, c, k = _place(n, c, k, rot, centre)
        ids = scene.add_polytope(n, c, k, args)
        front = ids[4]  # the -z face of the local plate looks at the camera (before the yaw)
        scene.rois.append(_Roi("sign", np.array([front]), k[[0, 2, 4, 6]]))


# --------------------------------------------------------------------------------------------
# Ray casting


@dataclass(frozen=True)
class _Camera:
    """Pinhole intrinsics plus per-pixel ray directions (world frame, camera-z component 1)."""

    f: float
    cx: float
    cy: float
    height: int
    width: int
    dirs: np.ndarray  # (H, W, 3) float32; t along these is the camera-frame depth
    unit: np.ndarray  # (H, W, 3) float32 normalised


def _camera(height: int, width: int, rot: np.ndarray) -> _Camera:
    f = focal_for_width(width)
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    d_cam = np.stack([(u - cx) / f, (v - cy) / f, np.ones_like(u)], axis=-1)
    dirs = d_cam @ rot.T
    unit = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
    return _Camera(f, cx, cy, height, width, dirs.astype(np.float32), unit.astype(np.float32))


def focal_for_width(width: int) -> float:
    """The synthetic camera's focal length: KITTI's (1242 px wide) scaled to ``width``."""
    return WIDTH_TO_FOCAL[1242] * width / 1242.0


def _project(
    points: np.ndarray, rot: np.ndarray, origin: np.ndarray, cam: _Camera
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel coordinates (u, v) and camera depth of world points."""
    pc = (points - origin) @ rot  # = R^T (p - o) for each row
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return cam.f * pc[:, 0] / z + cam.cx, cam.f * pc[:, 1] / z + cam.cy, z


def _window(prim: _Prim, rot: np.ndarray, origin: np.ndarray, cam: _Camera) -> tuple[slice, slice] | None:
    """The pixel rectangle that can see ``prim`` (its projected bounding box), or None."""
    u, v, z = _project(prim.corners, rot, origin, cam)
    if (z <= _NEAR).all():
        return None
    if (z <= _NEAR).any():  # straddles the image plane: projected corners do not bound it
        return slice(0, cam.height), slice(0, cam.width)
    u0, u1 = max(int(np.floor(u.min())), 0), min(int(np.ceil(u.max())) + 1, cam.width)
    v0, v1 = max(int(np.floor(v.min())), 0), min(int(np.ceil(v.max())) + 1, cam.height)
    if u0 >= u1 or v0 >= v1:
        return None
    return slice(v0, v1), slice(u0, u1)


def _hit(prim: _Prim, origin: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def ground_hits(scene: _Scene, dirs: np.ndarray, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def _trace(scene: _Scene, cam: _Camera, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth (inf where nothing is hit) and face id (-1 = sky) of the first hit for every pixel."""
    depth, face = ground_hits(scene, cam.dirs, origin)
    for prim in scene.prims:
        win = _window(prim, scene.rot, origin, cam)
        if win is None:
            continue
        t, plane = _hit(prim, origin, cam.dirs[win])
        closer = t < depth[win]
        depth[win] = np.where(closer, t, depth[win])
        face[win] = np.where(closer, plane.astype(np.int32) + prim.face0, face[win])
    return depth, face


# --------------------------------------------------------------------------------------------
# Shading


def _noise(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Smooth value noise in [0, 1] with unit lattice spacing (tiles every 256 units)."""
    fu, fv = np.floor(u), np.floor(v)
    a, b = u - fu, v - fv
    a = a * a * (3 - 2 * a)
    b = b * b * (3 - 2 * b)
    iu, iv = fu.astype(np.int64) & 255, fv.astype(np.int64) & 255
    iu1, iv1 = (iu + 1) & 255, (iv + 1) & 255
    iv, iv1 = iv << 8, iv1 << 8
    top = _TILE_FLAT.take(iv + iu) * (1 - a) + _TILE_FLAT.take(iv + iu1) * a
    bottom = _TILE_FLAT.take(iv1 + iu) * (1 - a) + _TILE_FLAT.take(iv1 + iu1) * a
    return (top * (1 - b) + bottom * b).astype(np.float32, copy=False)


def _fbm(
    u: np.ndarray, v: np.ndarray, footprint: np.ndarray | float, freq: float, octaves: int = 3
) -> np.ndarray:
    """Fractal value noise (mean ~0.5) at ``freq`` cycles per unit, band-limited to the pixel footprint.

    Octaves finer than ~2 px fade to their mean so distant surfaces do not alias (aliasing would
    differ between the views and masquerade as a stereo error).
    """
    total = np.zeros_like(u, dtype=np.float32)
    amp, norm = 1.0, 0.0
    for k in range(octaves):
        fr = freq * 2**k
        weight = np.clip(2.0 - 4.0 * footprint * fr, 0.0, 1.0)
        total += amp * weight * (_noise(u * fr + 17.3 * k, v * fr - 31.7 * k) - 0.5)
        norm += amp
        amp *= 0.5
    return 0.5 + total / norm * 1.6


def _rowdot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product of two (N, 3) arrays."""
    return np.einsum("ij,ij->i", a, b)


def _frac(x: np.ndarray) -> np.ndarray:
    return x - np.floor(x)


def _sky(scene: _Scene, d: np.ndarray) -> np.ndarray:
    """Sky colour along unit directions ``d``: horizon-to-zenith gradient with clouds."""
    e = -d[:, 1]
    t = np.clip(e / 0.6, 0, 1)[:, None] ** 0.6
    col = scene.sky_horizon * (1 - t) + scene.sky_zenith * t
    s = 1.0 / (np.maximum(e, 0.02) + 0.1)
    c = _fbm(d[:, 0] * s * 2 + scene.tex_shift[0], d[:, 2] * s * 2 + scene.tex_shift[1], 0.0, 1.0, 4)
    cover = np.clip((c - (1.05 - scene.cloud_cover * 0.6)) * 4, 0, 1)[:, None]
    return (col * (1 - cover) + np.float32(0.92) * cover).astype(np.float32)


def _environment(scene: _Scene, d: np.ndarray) -> np.ndarray:
    """What a mirror reflects along unit directions ``d``: sky, a skyline with windows, the street."""
    e = -d[:, 1]
    az = np.arctan2(d[:, 0], d[:, 2])
    col = _sky(scene, d)
    # Overhead: branches, wires and cloud edges as fine, high-contrast patches. A reflection's
    # content then shifts visibly between the two viewpoints (it lies at another depth).
    s = 1.0 / (np.maximum(e, 0.0) + 0.3)
    over = _fbm(d[:, 0] * s + scene.tex_shift[1], d[:, 2] * s, 0.0, 40.0, 3)
    dark = np.clip((over - 0.5) * 4, 0, 1)[:, None] * np.float32(scene.canopy)
    col = col * (1 - dark) + np.float32(0.12) * dark
    skyline = 0.05 + 0.35 * _noise(az * 4 + scene.tex_shift[0], np.full_like(az, 3.5))
    bld = (e >= 0) & (e < skyline)
    if bld.any():
        a, el = az[bld], e[bld]
        tone = 0.25 + 0.5 * _noise(np.floor(a * 10) * 7.1, np.full_like(a, 1.5))
        win = (_frac(a * 70) < 0.45) & (_frac(el * 45) < 0.5)
        shade = np.where(win, 0.08 + 0.9 * (_noise(a * 70, el * 45) > 0.7), tone)
        col[bld] = shade[:, None] * np.array([1.0, 0.97, 0.92], np.float32)
    ground = e < 0
    if ground.any():
        col[ground] = (0.22 + 0.15 * _noise(az[ground] * 30, e[ground] * 30))[:, None]
    return col


def _shade_road(scene: _Scene, h: dict[str, np.ndarray]) -> np.ndarray:
    """Asphalt with lane markings, paved sidewalks, grass beyond open sides."""
    r = scene.road
    x, z, fp = h["P"][:, 0], h["P"][:, 2], h["fp"]
    sx, sz = x + scene.tex_shift[0], z + scene.tex_shift[1]
    grain = _fbm(sx, sz, fp, 4.0, 3)
    patches = _fbm(sx * 0.7, sz, fp, 0.35, 3)  # repairs, stains, tyre tracks: survive distance
    col = (r["asphalt"] * (0.45 + 0.5 * grain + 0.5 * patches))[:, None] * np.ones(3, np.float32)
    lw = r["line_width"]
    dashed = _frac((z + r["phase"]) / r["period"]) < r["dash"] / r["period"]
    mark = np.zeros(x.shape, bool)
    for xl in r["lines"]:
        mark |= (np.abs(x - xl) < lw / 2) & dashed
    for edge in (r["left"] + 0.3, r["right"] - 0.3):
        mark |= np.abs(x - edge) < lw / 2
    col[mark] = (0.8 + 0.1 * grain[mark])[:, None]
    walk = (x < r["left"]) | (x > r["right"])
    if walk.any():
        tiles = (_frac(sx[walk] / 0.4) < 0.06) | (_frac(sz[walk] / 0.4) < 0.06)
        # Joints only where resolved; further away they average into a slightly darker tone.
        joint = np.where(fp[walk] < 0.02, np.where(tiles, 0.7, 1.0), 0.96)
        shade = (0.8 + 0.35 * (grain[walk] - 0.5) + 0.3 * (patches[walk] - 0.5)) * joint
        col[walk] = shade[:, None] * r["pave"]
        kerb = walk & ((np.abs(x - r["left"]) < 0.15) | (np.abs(x - r["right"]) < 0.15))
        col[kerb] = 0.75
    grass = (x < r["grass_left"]) | (x > r["grass_right"])
    if grass.any():
        g = _fbm(sx[grass] * 1.3, sz[grass], fp[grass], 3.0, 3)
        col[grass] = (0.4 + 0.9 * g)[:, None] * np.array([0.2, 0.38, 0.1], np.float32)
    return col


def _shade_wall(h: dict[str, np.ndarray]) -> np.ndarray:
    """Plaster or brick with a grid of windows above the ground floor."""
    u, v, fp, prm, col = h["u"], h["v"], h["fp"], h["prm"], h["col"]
    su, sv = h["su"], h["sv"]
    tone = 0.8 + 0.4 * (_fbm(su, sv, fp, 1.5, 3) - 0.5) + 0.25 * (_fbm(su, sv, fp, 12.0, 2) - 0.5)
    # Bricks only where a pixel resolves them (mortar lines would alias differently per view).
    brick = (prm[:, 4] > 0.5) & (fp < 0.03)
    if brick.any():
        row = np.floor(sv[brick] / 0.075)
        bu = su[brick] / 0.24 + 0.5 * (row % 2)
        mortar = (_frac(sv[brick] / 0.075) < 0.15) | (_frac(bu) < 0.06)
        per_brick = 0.75 + 0.5 * _noise(np.floor(bu) * 3.1, row * 1.7)
        tone[brick] = np.where(mortar, 1.35, per_brick)
    albedo = tone[:, None] * col
    fu, fv = _frac(u / prm[:, 0]), _frac(v / prm[:, 1])
    win = (
        (fu > 0.5 - prm[:, 2] / 2)
        & (fu < 0.5 + prm[:, 2] / 2)
        & (fv > 0.5 - prm[:, 3] / 2)
        & (fv < 0.5 + prm[:, 3] / 2)
        & (v > prm[:, 5])
        & (v < prm[:, 6] - 1.0)
    )
    if win.any():
        lit = _noise(np.floor(u[win] / prm[win, 0]) * 5.3, np.floor(v[win] / prm[win, 1]) * 2.9)
        albedo[win] = h["col2"][win] * (0.6 + 1.2 * lit)[:, None]
    return albedo


def _shade_foliage(h: dict[str, np.ndarray]) -> np.ndarray:
    leaves = _fbm(h["su"], h["sv"], h["fp"], 5.0, 3) * 0.6 + _fbm(h["su"], h["sv"], h["fp"], 0.7, 2) * 0.6
    return (0.2 + leaves)[:, None] * h["col"]


def _shade_paint(h: dict[str, np.ndarray]) -> np.ndarray:
    """Car paint with tail/head lights and a number plate on the front and back faces."""
    albedo = h["col"] * (0.92 + 0.16 * _fbm(h["su"], h["sv"], h["fp"], 3.0, 2))[:, None]
    u, v, kind = h["u"], h["v"], h["prm"][:, 0]
    ends = kind > 0.5
    if ends.any():
        au = np.abs(u[ends])
        lights = (v[ends] > 0.65) & (v[ends] < 0.82) & (au > 0.45) & (au < h["prm"][ends, 1] - 0.05)
        plate = (au < 0.26) & (v[ends] > 0.36) & (v[ends] < 0.47)
        lamp = np.where(
            (kind[ends] > 1.5)[:, None],
            np.array([0.7, 0.05, 0.04], np.float32),
            np.array([0.9, 0.9, 0.85], np.float32),
        )
        sub = albedo[ends]
        sub[lights] = lamp[lights]
        sub[plate] = 0.85
        albedo[ends] = sub
    return albedo


def _shade_sign(h: dict[str, np.ndarray]) -> np.ndarray:
    """Pictograms on the plate's front: prohibition ring, arrow, hazard stripes, direction text."""
    prm = h["prm"]
    a, b = h["u"] / prm[:, 1] + 0.5, h["v"] / prm[:, 2] + 0.5
    kind = prm[:, 0].astype(int)
    r = np.hypot(a - 0.5, b - 0.5)
    out = np.empty(a.shape + (3,), np.float32)
    white, red, blue = np.array([0.92, 0.92, 0.9]), np.array([0.8, 0.08, 0.06]), np.array([0.05, 0.2, 0.65])
    yellow, black, green = (
        np.array([0.95, 0.75, 0.05]),
        np.array([0.05, 0.05, 0.05]),
        np.array([0.05, 0.45, 0.2]),
    )
    k0 = kind == 0
    out[k0] = np.where(((r[k0] > 0.33) & (r[k0] < 0.47))[:, None], red, white)
    bars = k0 & (np.abs(a - 0.5) < 0.15) & (np.abs(b - 0.5) < 0.18) & (_frac(a * 7) < 0.5)
    out[bars] = black
    k1 = kind == 1
    arrow = (b > 0.2) & (b < 0.8) & (np.abs(a - 0.5) < 0.35 * (b - 0.2) / 0.6 + 0.05)
    out[k1] = np.where(arrow[k1][:, None], white, blue)
    k2 = kind == 2
    out[k2] = np.where((_frac((a + b) * 4)[k2] < 0.5)[:, None], yellow, black)
    k3 = kind == 3
    text = (_frac(b * 5) < 0.35) & (np.abs(a - 0.5) < 0.38) & (_frac(a * 9 + b * 3) < 0.7)
    out[k3] = np.where(text[k3][:, None], white, green)
    return out


def _shade(
    scene: _Scene, cam: _Camera, origin: np.ndarray, depth: np.ndarray, face: np.ndarray
) -> np.ndarray:
    """Colour (float RGB, ~[0, 1]) of every pixel of one view."""
    A = scene.arrays
    out = np.empty((cam.height * cam.width, 3), np.float32)
    fid = face.ravel()
    unit = cam.unit.reshape(-1, 3)
    sky = fid < 0
    if sky.any():
        out[sky] = _sky(scene, unit[sky])
    idx = np.nonzero(~sky)[0]
    if not idx.size:
        return out.reshape(cam.height, cam.width, 3)
    # Hit pixels sorted by material: each material's pixels are then a slice (a view, no copy).
    mat = A["mat"].take(fid[idx])
    idx = np.concatenate([idx[mat == m] for m in range(mat.max() + 1)])  # counting sort
    f = fid[idx]
    mat = A["mat"].take(f)
    t = depth.ravel()[idx]
    d = unit.take(idx, axis=0)
    P = origin.astype(np.float32) + cam.dirs.reshape(-1, 3).take(idx, axis=0) * t[:, None]

    def gather(key: str) -> np.ndarray:
        return A[key].take(f, axis=0)

    n = gather("normal")
    n_dot_v = -_rowdot(n, d)
    rel = P - gather("org")
    h = dict(
        P=P,
        d=d,
        n=n,
        u=_rowdot(rel, gather("uax")),
        v=_rowdot(rel, gather("vax")),
        col=gather("col"),
        col2=gather("col2"),
        prm=gather("prm"),
        # Metres of surface per pixel, the band limit of every texture: the geometric mean of
        # the footprint across (t/f) and along (t/f/cos) the view, so that a road seen at a
        # grazing angle keeps some texture instead of fading to flat grey.
        fp=t / np.float32(cam.f) / np.sqrt(np.maximum(np.abs(n_dot_v), np.float32(0.05))),
    )
    # Noise coordinates carry the per-frame shift; pattern coordinates (u, v) stay put.
    h["su"], h["sv"] = h["u"] + scene.tex_shift[0], h["v"] + scene.tex_shift[1]
    albedo = np.zeros((idx.size, 3), np.float32)
    extra = np.zeros((idx.size, 3), np.float32)  # light not from Lambert: reflections, interiors
    spec_k = np.zeros(idx.size, np.float32)
    shininess = np.ones(idx.size, np.float32)

    def subset(sel: np.ndarray) -> dict[str, np.ndarray]:
        return {k: a[sel] for k, a in h.items()}

    def reflection(sel: np.ndarray, f0: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Schlick-Fresnel weight and the environment along the mirrored view ray."""
        cos = np.clip(n_dot_v[sel], 0, 1)
        fres = f0 + (1 - f0) * (1 - cos) ** 5
        mirrored = d[sel] + 2 * cos[:, None] * n[sel]
        return fres.astype(np.float32), _environment(scene, mirrored)

    bounds = np.searchsorted(mat, np.arange(mat[-1] + 2))
    for m in np.unique(mat):
        sel = slice(bounds[m], bounds[m + 1])
        s = subset(sel)
        if m == ROAD:
            albedo[sel] = _shade_road(scene, s)
        elif m == WALL:
            albedo[sel] = _shade_wall(s)
            spec_k[sel], shininess[sel] = 0.15, 40
        elif m == FOLIAGE:
            albedo[sel] = _shade_foliage(s)
        elif m == PAINT:
            albedo[sel] = _shade_paint(s)
            fres, env = reflection(sel, 0.04)  # clear coat: a faint reflection
            extra[sel] = 0.3 * fres[:, None] * env
            spec_k[sel], shininess[sel] = 0.8, 60
        elif m == GLASS:
            fres, env = reflection(sel, s["prm"][:, 0])
            # The interior sits behind the glass: sample it further along the ray.
            q = s["P"] + s["d"] * s["prm"][:, 1:2]
            inside = _fbm(q[:, 0] * 1.7 + q[:, 1] * 1.1, q[:, 2] * 1.7 - q[:, 1] * 0.9, s["fp"], 1.5, 3)
            interior = s["col"] * (0.4 + 1.6 * inside)[:, None] * np.float32(scene.ambient * 2.5)
            extra[sel] = (1 - fres)[:, None] * interior + fres[:, None] * env
            spec_k[sel], shininess[sel] = 6.0, 400
        elif m == TYRE:
            albedo[sel] = s["col"] * (0.8 + 0.4 * _fbm(s["su"], s["sv"], s["fp"], 8.0, 2))[:, None]
        elif m == POLE or m == METAL:
            albedo[sel] = s["col"] * (0.85 + 0.3 * _fbm(s["su"], s["sv"], s["fp"], 6.0, 2))[:, None]
            spec_k[sel], shininess[sel] = 0.5, 30
        elif m == SIGN:
            albedo[sel] = _shade_sign(s)
            fres, env = reflection(sel, 0.2)  # glossy, partly retro-reflective film
            extra[sel] = s["prm"][:, 3:4] * fres[:, None] * env
            spec_k[sel], shininess[sel] = 1.5 * s["prm"][:, 3], 20
    n_dot_l = np.clip(n @ scene.sun.astype(np.float32), 0, None)
    half = scene.sun.astype(np.float32) - d
    half /= np.sqrt(_rowdot(half, half))[:, None]
    n_dot_h = np.clip(_rowdot(n, half), 0, None)
    # The highlight only where it can matter (0.6 ** 20 is already ~4e-5): pow is slow.
    lit = np.nonzero((spec_k > 0) & (n_dot_h > 0.6) & (n_dot_l > 0))[0]
    spec = np.zeros_like(spec_k)
    spec[lit] = spec_k[lit] * n_dot_h[lit] ** shininess[lit]
    light = (scene.ambient + n_dot_l)[:, None] * scene.sun_colour.astype(np.float32)
    out[idx] = albedo * light + spec[:, None] * scene.sun_colour.astype(np.float32) + extra
    return out.reshape(cam.height, cam.width, 3)


# --------------------------------------------------------------------------------------------
# Frames


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


def _rois(scene: _Scene, cam: _Camera, face: np.ndarray) -> list[tuple[str, int, int, int, int]]:
    """Boxes of the scene's ROIs in the left view, dropping tiny and mostly hidden ones."""
    boxes = []
    origin = np.zeros(3)
    for roi in scene.rois:
        u, v, z = _project(roi.corners, scene.rot, origin, cam)
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


def _class_map(scene: _Scene, face: np.ndarray) -> np.ndarray:
    """Per pixel of the left view, the bits of the ROI classes whose faces it shows."""
    out = np.zeros(face.shape, np.uint8)
    for cls, bit in CLASS_BITS.items():
        faces = [roi.faces for roi in scene.rois if roi.cls == cls]
        if faces:
            out[np.isin(face, np.concatenate(faces))] |= np.uint8(bit)
    return out


def render_frame(seed: int, split: int, index: int, height: int, width: int, lidar: bool = False) -> Frame:
    """Render frame ``index`` of ``split`` (0 = training, 1 = evaluation) deterministically.

    ``lidar``: also scan the scene with the simulated Velodyne (``Frame.scan``); the scan has its
    own generator, so everything else is the same either way.
    """
    rng = frame_rng(seed, split, index)
    scene = _build_scene(rng)
    cam = _camera(height, width, scene.rot)
    f = cam.f
    views, depths, faces = [], [], []
    for offset in (0.0, KITTI_BASELINE):
        origin = scene.rot @ np.array([offset, 0.0, 0.0])
        depth, face = _trace(scene, cam, origin)
        views.append(_shade(scene, cam, origin, depth, face))
        depths.append(depth)
        faces.append(face)
    images = []
    for view in views:  # a little sensor noise and exposure mismatch per view
        gain = rng.uniform(0.985, 1.015)
        noisy = view * gain + rng.standard_normal(view.shape, dtype=np.float32) * np.float32(0.008)
        images.append((np.clip(noisy, 0, 1) * 255 + 0.5).astype(np.uint8))
    with np.errstate(divide="ignore"):
        disp, disp_right = (
            np.where(np.isfinite(z), f * KITTI_BASELINE / z, 0).astype(np.float32) for z in depths
        )
    inst = scene.arrays["inst"][np.maximum(faces[0], 0)] * (faces[0] >= 0)
    present = np.unique(inst[inst > 0])
    lookup = np.zeros(int(inst.max()) + 1, np.uint8)
    lookup[present] = np.arange(1, present.size + 1)  # renumber visible cars 1..n
    scan = None
    if lidar:
        from . import velodyne_sim  # imports this module's geometry: imported here, not at the top

        scan = velodyne_sim.simulate(scene, f, width, velodyne_sim.scan_rng(seed, split, index))
    return Frame(
        left=images[0],
        right=images[1],
        disp=disp,
        disp_right=disp_right,
        noc=non_occluded(disp, disp_right),
        obj_map=lookup[inst],
        class_map=_class_map(scene, faces[0]),
        rois=_rois(scene, cam, faces[0]),
        rotation=scene.rot,
        cam_height=scene.cam_height,
        focal=f,
        scan=scan,
    )


# --------------------------------------------------------------------------------------------
# Writing the KITTI-format tree


def calib_text(height: int, width: int, raw: bool = False) -> str:
    """A raw-data style ``calib_cam_to_cam.txt`` for the synthetic rig (cameras 02 and 03).

    ``raw``: the file of a raw day folder, which the raw-LiDAR GT is projected with. It also has
    ``R_rect_00`` (identity: the rig is rectified), and its principal points are in KITTI's
    MATLAB convention (1-based pixels, one more than the 0-based image centre), which the field's
    projection assumes when it takes ``round(u) - 1`` as the pixel (:func:`kitti.lidar_depth_map`):
    a point then lands on the pixel that shows it. The KITTI 2015 files (``raw=False``) keep the
    0-based centre; only the focal and baseline are read from them.
    """
    f = focal_for_width(width)
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    if raw:
        cx, cy = cx + 1.0, cy + 1.0

    def row(key: str, values: Iterable[float]) -> str:
        return f"{key}: " + " ".join(f"{v:.12e}" for v in values) + "\n"

    text = "calib_time: 01-Jan-2017 00:00:00\ncorner_dist: 0.000000e+00\n"
    if raw:
        text += row("R_rect_00", np.eye(3).ravel())
    for cam, tx in (("02", 0.0), ("03", -KITTI_BASELINE)):
        text += row(f"S_{cam}", (width, height))
        text += row(f"K_{cam}", (f, 0, cx, 0, f, cy, 0, 0, 1))
        text += row(f"D_{cam}", (0, 0, 0, 0, 0))
        text += row(f"R_{cam}", np.eye(3).ravel())
        text += row(f"T_{cam}", (tx, 0, 0))
        text += row(f"S_rect_{cam}", (width, height))
        text += row(f"R_rect_{cam}", np.eye(3).ravel())
        text += row(f"P_rect_{cam}", (f, 0, cx, f * tx, 0, f, cy, 0, 0, 0, 1, 0))
    return text


def train_drive(cfg: SyntheticConfig, index: int) -> tuple[str, int]:
    """``(drive folder relative to raw/, frame number)`` of training pair ``index``."""
    drive = index * cfg.drives // cfg.train_pairs
    first = -(-drive * cfg.train_pairs // cfg.drives)  # first index mapped to this drive
    date = DATES[drive % len(DATES)]
    return f"{date}/{date}_drive_{drive + 1:04d}_sync", index - first


def _write_train(job: tuple[SyntheticConfig, str, int]) -> tuple[str, str]:
    cfg, root, index = job
    frame = render_frame(cfg.seed, _TRAIN, index, cfg.height, cfg.width)
    drive, number = train_drive(cfg, index)
    name = f"{number:010d}.png"
    raw = Path(root) / "raw"
    left, right = f"{drive}/image_02/data/{name}", f"{drive}/image_03/data/{name}"
    write_png(raw / left, frame.left)
    write_png(raw / right, frame.right)
    write_disparity(raw / drive / "disp_02" / "data" / name, frame.disp)
    return left, right


def within_range(disp: np.ndarray, focal: float, max_depth: float) -> np.ndarray:
    """``disp`` with pixels deeper than ``max_depth`` metres set invalid (0); 0 = no limit.

    KITTI's GT comes from a LiDAR that returns nothing past ~80 m; a rendered road reaches the
    horizon (kilometres), which would otherwise dominate RMSE against predictions capped at 80 m.
    """
    if max_depth <= 0:
        return disp
    return np.where(disp >= focal * KITTI_BASELINE / max_depth, disp, 0).astype(disp.dtype)


def eval_drive() -> str:
    """The raw drive folder (relative to ``raw/``) of the evaluation frames and their scans."""
    return f"{EVAL_DATE}/{EVAL_DATE}_drive_{EVAL_DRIVE:04d}_sync"


def _write_eval(
    job: tuple[SyntheticConfig, str, int, bool],
) -> tuple[list[tuple[str, str, int, int, int, int]], dict[str, int] | None]:
    """Write evaluation frame ``index``; returns its ROI rows and (with the LiDAR) its scan's counts."""
    cfg, root, index, lidar = job
    frame = render_frame(cfg.seed, _EVAL, index, cfg.height, cfg.width, lidar=lidar)
    name = f"{index:06d}_10"
    training = Path(root) / "kitti2015" / "training"
    write_png(training / "image_2" / f"{name}.png", frame.left)
    write_png(training / "image_3" / f"{name}.png", frame.right)
    disp = within_range(frame.disp, frame.focal, cfg.gt_max_depth)
    write_disparity(training / EVAL_GT_OCC / f"{name}.png", disp)
    write_disparity(training / EVAL_GT_NOC / f"{name}.png", np.where(frame.noc, disp, 0))
    write_png(training / "obj_map" / f"{name}.png", frame.obj_map)
    write_png(training / "class_map" / f"{name}.png", frame.class_map)
    write_text(training / "calib_cam_to_cam" / f"{index:06d}.txt", calib_text(cfg.height, cfg.width))
    rows = [(name, *box) for box in frame.rois]
    if not lidar:
        return rows, None
    # The same frame as a raw drive frame: images (copies of the files above), scan.
    raw = Path(root) / "raw"
    drive, number = raw / eval_drive(), f"{index:010d}"
    for src, cam in (("image_2", "image_02"), ("image_3", "image_03")):
        with atomic_path(drive / cam / "data" / f"{number}.png") as tmp:
            shutil.copyfile(training / src / f"{name}.png", tmp)
    scan_path = drive / "velodyne_points" / "data" / f"{number}.bin"
    write_velodyne(scan_path, frame.scan.points)
    gt = velodyne_depth(scan_path, read_raw_calib(raw / EVAL_DATE))  # as the evaluation reads it
    return rows, {"points": int(len(frame.scan.points)), "gt_pixels": int((gt > 0).sum())}


def _run(fn: Callable, jobs: list, workers: int, bar) -> list:
    """Map ``fn`` over ``jobs`` in order, in worker processes when ``workers > 1``."""
    if workers <= 1:
        results = []
        for job in jobs:
            results.append(fn(job))
            bar.update(1)
        return results
    # spawn: a forked child could inherit locks held by threads of torch/OpenCV in the parent.
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        results = []
        for result in pool.map(fn, jobs, chunksize=max(1, min(16, len(jobs) // (4 * workers)))):
            results.append(result)
            bar.update(1)
        return results


def generate(
    cfg: SyntheticConfig, root: Path, progress: bool = True, workers: int | None = None, lidar: bool = True
) -> dict:
    """Render the whole synthetic set under ``root`` in KITTI's layouts; returns a summary.

    Always regenerates from scratch (``root/raw`` and ``root/kitti2015`` are replaced); every
    file is written atomically and the output depends only on ``cfg`` (byte-identical reruns).
    ``workers`` processes render in parallel (default: the CPUs available to this process).

    The evaluation frames are written twice: as KITTI 2015 frames ``NNNNNN_10`` and, with a
    simulated Velodyne scan each, as frames ``NNNNNNNNNN`` of the raw drive :func:`eval_drive`
    (same image bytes), listed in ``eigen_test_files.txt``. ``lidar=False`` skips the latter
    (for timing; nothing else changes).
    """
    from tqdm import tqdm

    from . import velodyne_sim  # imports this module's geometry: imported here, not at the top

    root = Path(root)
    if cfg.drives >= EVAL_DRIVE:
        raise ValueError(f"at most {EVAL_DRIVE - 1} drives: drive {EVAL_DRIVE} holds the evaluation frames")
    if workers is None:
        workers = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    for sub in ("raw", "kitti2015"):
        if (root / sub).exists():
            shutil.rmtree(root / sub)
    (root / EIGEN_TEST_FILES).unlink(missing_ok=True)
    raw, k2015 = root / "raw", root / "kitti2015"
    dates = {train_drive(cfg, i)[0].split("/")[0] for i in range(cfg.train_pairs)}
    if lidar and cfg.eval_frames:
        dates.add(EVAL_DATE)
    for date in sorted(dates):
        write_text(raw / date / "calib_cam_to_cam.txt", calib_text(cfg.height, cfg.width, raw=True))
        if lidar:
            write_text(raw / date / "calib_velo_to_cam.txt", velodyne_sim.calib_velo_to_cam_text())

    key = str(root)
    with tqdm(
        total=cfg.train_pairs + cfg.eval_frames, desc="synthetic", unit="frame", disable=not progress
    ) as bar:
        pairs = _run(_write_train, [(cfg, key, i) for i in range(cfg.train_pairs)], workers, bar)
        evals = _run(_write_eval, [(cfg, key, i, lidar) for i in range(cfg.eval_frames)], workers, bar)
    boxes = [rows for rows, _ in evals]

    write_split(root / "train_files.txt", pairs)
    names = [f"{i:06d}_10" for i in range(cfg.eval_frames)]
    write_split(
        k2015 / "test_files.txt", [(f"training/image_2/{n}.png", f"training/image_3/{n}.png") for n in names]
    )
    rois = pd.DataFrame(
        [row for rows in boxes for row in rows], columns=["image", "class", "x0", "y0", "x1", "y1"]
    )
    write_rois(root / "rois.csv", rois)
    summary = {
        "config": dataclasses.asdict(cfg),
        "focal_px": focal_for_width(cfg.width),
        "baseline_m": KITTI_BASELINE,
        "train_pairs": len(pairs),
        "eval_frames": len(names),
        "drives": len({train_drive(cfg, i)[0] for i in range(cfg.train_pairs)}),
        "rois": {c: int((rois["class"] == c).sum()) for c in ("car", "windshield", "glass", "sign")},
    }
    if lidar and cfg.eval_frames:
        drive = eval_drive()
        write_split(
            root / EIGEN_TEST_FILES,
            [
                (f"{drive}/image_02/data/{i:010d}.png", f"{drive}/image_03/data/{i:010d}.png")
                for i in range(cfg.eval_frames)
            ],
        )

        def spread(key: str) -> dict[str, float | int]:
            values = np.array([counts[key] for _, counts in evals], float)
            return {"mean": float(values.mean()), "min": int(values.min()), "max": int(values.max())}

        summary["lidar"] = {
            "drive": drive,
            "points_per_scan": spread("points"),
            "gt_pixels_per_frame": spread("gt_pixels"),  # lidar_depth_map at the evaluation size
        }
    write_json(root / "synthetic.json", summary)
    return summary
