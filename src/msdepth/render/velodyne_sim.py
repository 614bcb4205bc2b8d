"""A simulated Velodyne HDL-64E on the synthetic rig: the scan KITTI's raw-LiDAR ground truth comes from.

The scanner is bolted to the camera car as on KITTI's: rigidly mounted to camera 02 (so it
follows the synthetic camera's random height, yaw, pitch and roll), 0.27 m behind and 0.08 m
above it. Its rays are cast into the frame's own scene with the renderer's own first-hit search
(:func:`.raycast.first_hits`: the analytic ground plane, then the scene's primitives), so the
scan sees exactly the surfaces the images show. Only the azimuths that can land in the camera's
field of view (plus :data:`FOV_MARGIN_DEG`) are cast: the rest of a
real 360-degree sweep would never reach the evaluation.

Returns are exact: no range noise, no beam divergence, no mixed pixels. The synthetic GT is
meant to be precise; what the scan does model is where a LiDAR has no return (sky, beyond
:data:`MAX_RANGE`, dropped at glass) and what it sees through glass.

Glass (windshields, side windows, shop windows): the scene has no interior geometry (a cabin
and a building are solid polytopes, a shop window is a thin slab in front of a solid wall); the
renderer paints the interior as a texture ``prm[1]`` metres behind the glass along the view ray
(:mod:`.shading`: the car's interior depth 0.8-1.6 m, a shop's 1.5-4 m). A LiDAR ray whose
first surface is glass is dropped with probability :data:`GLASS_DROP`; otherwise it transmits and
returns from that same virtual interior, ``prm[1]`` metres beyond the glass along the ray (or
not at all if that lies beyond the range). Nothing else is looked up behind the glass, so a
return is the interior the images show, never the wall a shop window is mounted on.

The drop decisions come from their own generator (:func:`scan_rng`), seeded from the frame's
(seed, split, index) plus a tag: the renderer's stream is never touched, so the images and GT
of a frame are the same with or without its scan.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msdepth.render.raycast import first_hits
from msdepth.render.scene import (
    FOLIAGE,
    GLASS,
    METAL,
    PAINT,
    POLE,
    ROAD,
    SIGN,
    TYRE,
    WALL,
    Prim,
    Scene,
)

# The Velodyne HDL-64E: 64 beams evenly spread over +2.0 .. -24.8 degrees of elevation, one
# firing every 0.09 degrees of azimuth (10 Hz), returns up to ~120 m.
N_BEAMS = 64
ELEVATION_TOP_DEG = 2.0
ELEVATION_BOTTOM_DEG = -24.8
AZIMUTH_STEP_DEG = 0.09
MAX_RANGE = 120.0  # m

# The mount. These numbers approximate KITTI's rig (its calib_velo_to_cam.txt, rounded):
# velo x forward, y left, z up -> camera x right, y down, z forward, with camera 02 0.27 m ahead
# of and 0.08 m below the LiDAR (p_cam = R p_velo + T). On KITTI the LiDAR is 1.73 m above the
# ground (the camera 1.65 m); here the camera height is drawn per frame, and the rigid mount puts
# the LiDAR at the camera height + 0.076 m (LIDAR_HEIGHT is KITTI's figure, for reference).
VELO_TO_CAM_R = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
VELO_TO_CAM_T = np.array([-0.004, -0.076, -0.272])
LIDAR_HEIGHT = 1.73  # m

FOV_MARGIN_DEG = 1.0  # azimuths cast beyond the camera's half field of view, each side
GLASS_DROP = 0.3  # probability that a ray whose first surface is glass returns nothing

# Reflectance: a deterministic stand-in for KITTI's remission, base value per material times
# (0.4 + 0.6 cos incidence). Foliage is bright in the near infrared, signs are retro-reflective,
# tyres black; for glass the value is that of the interior seen through it.
_REFLECTIVITY = {
    ROAD: 0.2,
    WALL: 0.45,
    FOLIAGE: 0.6,
    PAINT: 0.35,
    GLASS: 0.1,
    TYRE: 0.05,
    POLE: 0.4,
    SIGN: 0.95,
    METAL: 0.5,
}
_SCAN_STREAM = 0x5CA7  # seed-stream tag of the scan's own generator
_EPS = 1e-5  # slack of the angular culling (float32 ray directions)


@dataclass
class Scan:
    """One frame's scan: KITTI's point layout plus counts about the rays behind it."""

    points: np.ndarray  # float32 (N, 4): x forward, y left, z up (m, LiDAR frame), reflectance
    rays: int  # rays cast (beams x azimuths inside the camera's field of view)
    glass_hits: int  # rays whose first surface (within range) is glass
    glass_dropped: int  # of those, the rays that returned nothing


def _elevations() -> np.ndarray:
    """The beams' elevations (radians, top beam first)."""
    return np.radians(np.linspace(ELEVATION_TOP_DEG, ELEVATION_BOTTOM_DEG, N_BEAMS))


def azimuths(focal: float, width: int) -> np.ndarray:
    """The azimuths cast (radians, increasing = to the left): multiples of the step that can
    reach an image ``width`` px wide with focal ``focal``, plus the margin.

    The LiDAR sits behind the camera, so a point the camera sees appears at a smaller azimuth
    from the LiDAR than its angle from the camera's axis (the 4 mm sideways offset is far too
    small to undo that): the camera's half field of view bounds every useful azimuth.
    """
    half = np.degrees(np.arctan((width / 2.0) / focal)) + FOV_MARGIN_DEG
    k = int(np.floor(half / AZIMUTH_STEP_DEG))
    return np.radians(np.arange(-k, k + 1) * AZIMUTH_STEP_DEG)


def scan_rng(seed: int, split: int, index: int) -> np.random.Generator:
    """The scan's generator for frame ``(seed, split, index)``, independent of the renderer's."""
    return np.random.default_rng([seed, split, index, _SCAN_STREAM])


def calib_velo_to_cam_text() -> str:
    """``calib_velo_to_cam.txt`` as KITTI writes it (R row-major, T in metres)."""

    def row(key: str, values: np.ndarray) -> str:
        return f"{key}: " + " ".join(f"{v:.6e}" for v in np.ravel(values)) + "\n"

    return (
        "calib_time: 01-Jan-2017 00:00:00\n"
        + row("R", VELO_TO_CAM_R)
        + row("T", VELO_TO_CAM_T)
        + "delta_f: 0.000000e+00 0.000000e+00\n"
        + "delta_c: 0.000000e+00 0.000000e+00\n"
    )


def _grid_window(
    prim: Prim, origin: np.ndarray, world_to_velo: np.ndarray, elev: np.ndarray, az: np.ndarray
) -> tuple[slice, slice] | None:
    """The (beam, azimuth) rectangle of rays that can hit ``prim``, or None.

    A convex polytope in front of the LiDAR (x > 0) projects onto the plane x = 1 inside the
    bounding box of its projected corners; a ray (e, a) meets that plane at (tan a, tan e / cos a).
    """
    c = (prim.corners - origin) @ world_to_velo.T
    x = c[:, 0]
    if (x <= 0).all():
        return None  # every ray runs forward (cos e cos a > 0): never reaches x <= 0
    if (x <= 1e-3).any():  # straddles the LiDAR's plane: the projection is unbounded
        return slice(0, elev.size), slice(0, az.size)
    p, q = c[:, 1] / x, c[:, 2] / x
    cols = np.nonzero((az >= np.arctan(p.min()) - _EPS) & (az <= np.arctan(p.max()) + _EPS))[0]
    if not cols.size:
        return None
    cos_min = min(np.cos(az[cols[0]]), np.cos(az[cols[-1]]))
    lo, hi = min(q.min(), q.min() * cos_min), max(q.max(), q.max() * cos_min)
    tan_e = np.tan(elev)
    rows = np.nonzero((tan_e >= lo - _EPS) & (tan_e <= hi + _EPS))[0]
    if not rows.size:
        return None
    return slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1)


def simulate(
    scene: Scene, focal: float, width: int, rng: np.random.Generator, glass_drop: float = GLASS_DROP
) -> Scan:
    """Scan ``scene`` from the LiDAR rigidly mounted on its camera (focal/width: the camera-2 image).

    ``rng`` (see :func:`scan_rng`) decides the glass drops: one uniform draw per ray cast, so the
    scan depends only on the scene, the image geometry and the generator's seed.
    """
    elev, az = _elevations(), azimuths(focal, width)
    e, a = np.meshgrid(elev, az, indexing="ij")
    d_velo = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1)
    velo_to_world = scene.rot @ VELO_TO_CAM_R  # world: x right, y down, z forward (as the renderer)
    origin = scene.rot @ VELO_TO_CAM_T  # the LiDAR's centre; camera 02 is the world origin
    dirs = (d_velo @ velo_to_world.T).astype(np.float32)
    world_to_velo = velo_to_world.T
    rng_, face = first_hits(
        scene, dirs, origin, lambda prim: _grid_window(prim, origin, world_to_velo, elev, az)
    )
    draws = rng.random(rng_.shape)

    A = scene.arrays
    hit = np.isfinite(rng_) & (rng_ <= MAX_RANGE)
    mat = np.where(hit, A["mat"][np.maximum(face, 0)], -1)
    glass = mat == GLASS
    dropped = glass & (draws < glass_drop)
    through = glass & ~dropped
    # Transmitted: the return comes from the painted interior prm[1] m beyond the glass.
    behind = A["prm"][np.maximum(face, 0), 1]
    distance = np.where(through, rng_ + behind, rng_)
    keep = hit & ~dropped & (distance <= MAX_RANGE)

    normal = A["normal"][face[keep]]
    cos_inc = np.abs(np.einsum("ij,ij->i", normal, dirs[keep]))
    base = np.zeros(max(_REFLECTIVITY) + 1, np.float32)
    base[list(_REFLECTIVITY)] = list(_REFLECTIVITY.values())
    reflectance = np.clip(base[mat[keep]] * (0.4 + 0.6 * cos_inc), 0.0, 1.0)
    xyz = distance[keep].astype(np.float64)[:, None] * d_velo[keep]
    points = np.concatenate([xyz, reflectance[:, None]], axis=1).astype(np.float32)
    return Scan(points, int(rng_.size), int(glass.sum()), int(dropped.sum()))
