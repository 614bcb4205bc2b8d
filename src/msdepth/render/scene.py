"""A frame's scene: material ids, convex primitives with per-face shading attributes, ROIs.

The data model the street builders (:mod:`.street`, :mod:`.cars`) fill in and the ray casting
(:mod:`.raycast`), shading (:mod:`.shading`) and the simulated Velodyne (:mod:`.velodyne_sim`)
read, with the small geometry helpers they share.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Iterable

import numpy as np

# Material ids.
ROAD, WALL, FOLIAGE, PAINT, GLASS, TYRE, POLE, SIGN, METAL = range(9)

# Index of refraction of glass (car glass and shop windows), drawn uniformly per pane: laminated
# windshields' PVB interlayer n ~ 1.48 to soda-lime float glass n_D ~ 1.52-1.53 (docs/glass.md).
GLASS_IOR = (1.48, 1.53)


def fresnel_f0(ior: np.ndarray | float) -> np.ndarray | float:
    """Normal-incidence reflectance of an uncoated dielectric in air: ((n - 1) / (n + 1))**2."""
    return ((ior - 1) / (ior + 1)) ** 2


@dataclass
class Roi:
    """An evaluation box: its class, the faces that belong to it, and 3-D points spanning it."""

    cls: str
    faces: np.ndarray
    corners: np.ndarray


@dataclass
class Prim:
    """A convex polytope ``{p : normals @ p <= offsets}`` whose faces start at ``face0``."""

    normals: np.ndarray
    offsets: np.ndarray
    corners: np.ndarray
    face0: int


@dataclass
class Scene:
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
    prims: list[Prim] = field(default_factory=list)
    rois: list[Roi] = field(default_factory=list)
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
            Prim(
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


def box_planes(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Planes (-x, +x, -y, +y, -z, +z) and 8 corners of an axis-aligned box."""
    normals = np.array([[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]], float)
    offsets = np.array([-lo[0], hi[0], -lo[1], hi[1], -lo[2], hi[2]], float)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return normals, offsets, corners


def yaw_matrix(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def place(
    normals: np.ndarray, offsets: np.ndarray, corners: np.ndarray, rot: np.ndarray, pos: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Move a polytope given in a local frame by rotation ``rot`` and translation ``pos``."""
    n = normals @ rot.T
    return n, offsets + n @ pos, corners @ rot.T + pos


def camera_rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
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


def hsv(h: float, s: float, v: float) -> np.ndarray:
    """An RGB colour from hue/saturation/value in [0, 1]."""
    i = int(h * 6) % 6
    f = h * 6 - int(h * 6)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    return np.array([(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i])


# Adds an axis-aligned box: (lo, hi, face attributes given the face normal) -> face ids.
BoxFn = Callable[[Iterable[float], Iterable[float], Callable[[np.ndarray], dict[str, Any]]], list[int]]
