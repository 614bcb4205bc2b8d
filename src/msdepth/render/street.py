"""Drawing one random street: camera pose, lighting, road, facades or open land, poles and signs.

All randomness of a frame's layout comes from the frame's generator, drawn in a fixed order
(the rendered set's bytes depend on it).
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from msdepth.render.cars import CAR_COUNT, CAR_DEPTH, add_cars
from msdepth.render.scene import (
    FOLIAGE,
    GLASS,
    GLASS_IOR,
    METAL,
    POLE,
    ROAD,
    SIGN,
    WALL,
    BoxFn,
    Roi,
    Scene,
    box_planes,
    camera_rotation,
    hsv,
    place,
    yaw_matrix,
)

_UP = np.array([0.0, -1.0, 0.0])


def build_scene(
    rng: np.random.Generator,
    car_count: tuple[int, int] = CAR_COUNT,
    car_depth: tuple[float, float] = CAR_DEPTH,
) -> Scene:
    """Draw one random street scene (all randomness of the frame's layout comes from ``rng``);
    ``car_count`` and ``car_depth``: its cars' (:func:`~msdepth.render.cars.add_cars`)."""
    u = rng.uniform
    cam_h = u(1.4, 1.9)
    rot = camera_rotation(np.radians(u(-4, 4)), np.radians(u(-3, 3)), np.radians(u(-1, 1)))
    sun = np.array([u(-1, 1), -u(0.3, 1.2), u(-0.6, 1.0)])
    warm = u(0, 0.15)
    horizon = hsv(u(0.52, 0.62), u(0.05, 0.3), u(0.75, 0.95))
    zenith = hsv(u(0.55, 0.65), u(0.3, 0.7), u(0.5, 0.85))

    sides = _draw_sides(rng)
    road = _draw_road(rng, sides)
    scene = Scene(
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
        normals, offsets, corners = box_planes(np.asarray(lo, float), np.asarray(hi, float))
        return scene.add_polytope(normals, offsets, corners, [faces(n) for n in normals])

    for s, side in sides.items():
        if side["built"]:
            _add_facades(scene, rng, s, side["dist"], ground, box)
        else:
            _add_open_side(scene, rng, s, side["dist"], ground, box)
    if rng.random() < 0.45:
        _add_far_building(scene, rng, ground, box)

    add_cars(scene, rng, sides, road, car_count, car_depth)
    _add_poles(scene, rng, sides, ground, box)
    scene.finalise()
    return scene


def _draw_sides(rng: np.random.Generator) -> dict[int, dict[str, Any]]:
    """The street's cross-section: each side (-1 left, 1 right) has a facade line (or open land)
    3-15 m away, behind a sidewalk that starts at ``edge`` (the road's border, signed x)."""
    u = rng.uniform
    sides: dict[int, dict[str, Any]] = {}
    for s in (-1, 1):
        dist = u(3, 15)
        sidewalk = u(1.0, max(1.0, min(4.0, dist - 2.0)))
        sides[s] = dict(built=rng.random() < 0.8, dist=dist, sidewalk=sidewalk, edge=s * (dist - sidewalk))
    return sides


def _draw_road(rng: np.random.Generator, sides: dict[int, dict[str, Any]]) -> dict[str, Any]:
    """The road between the sidewalks: lanes and markings, asphalt, paving, grass on open sides."""
    u = rng.uniform
    left, right = sides[-1]["edge"], sides[1]["edge"]
    lane = u(2.8, 3.6)
    lines = list(np.arange(left + lane, right - 1.0, lane))
    return dict(
        left=left,
        right=right,
        lines=np.array(lines),
        line_width=u(0.1, 0.16),
        dash=u(2, 4),
        period=u(7, 12),
        phase=u(0, 10),
        asphalt=u(0.22, 0.38),
        pave=hsv(u(0.05, 0.12), u(0.05, 0.25), u(0.5, 0.7)),
        grass_left=-sides[-1]["dist"] if not sides[-1]["built"] else -1e9,
        grass_right=sides[1]["dist"] if not sides[1]["built"] else 1e9,
    )


def _add_far_building(scene: Scene, rng: np.random.Generator, ground: np.ndarray, box: BoxFn) -> None:
    """A building closing the street far ahead."""
    u = rng.uniform
    cam_h = scene.cam_height
    zf, height = u(45, 150), u(8, 30)
    colour = hsv(u(0, 1), u(0.05, 0.35), u(0.35, 0.8))
    prm = (u(1.6, 3.5), u(2.8, 3.6), u(0.35, 0.65), u(0.4, 0.65), float(rng.random() < 0.3), 3.0, height)
    box(
        (-90, cam_h - height, zf),
        (90, cam_h + 0.1, zf + 12),
        lambda n: dict(material=WALL, origin=ground, colour=colour, colour2=(0.1, 0.12, 0.16), params=prm),
    )


def _add_facades(
    scene: Scene, rng: np.random.Generator, s: int, dist: float, ground: np.ndarray, box: BoxFn
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
        colour = hsv(u(0, 1), u(0.05, 0.4), u(0.3, 0.85))
        window = hsv(u(0.5, 0.7), u(0.1, 0.4), u(0.08, 0.3))
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
            tint = hsv(u(0, 1), u(0.1, 0.5), u(0.1, 0.35))
            glass = dict(material=GLASS, origin=ground, colour=tint, params=(u(*GLASS_IOR), u(1.5, 4.0)))
            ids = box((xs[0], top, z0), (xs[1], bottom, z1), lambda n: glass)  # noqa: B023 - box() calls it at once
            front = ids[0] if s > 0 else ids[1]  # the face looking at the street
            x = s * (d - 0.04)
            scene.rois.append(
                Roi(
                    "glass",
                    np.array([front]),
                    np.array([[x, top, z0], [x, bottom, z0], [x, top, z1], [x, bottom, z1]]),
                )
            )
        z += length


def _add_open_side(
    scene: Scene, rng: np.random.Generator, s: int, dist: float, ground: np.ndarray, box: BoxFn
) -> None:
    """No buildings: a hedge along the road and/or a distant tree line across a field."""
    u = rng.uniform
    cam_h = scene.cam_height
    green = hsv(u(0.22, 0.36), u(0.4, 0.8), u(0.2, 0.5))
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


def _add_poles(scene: Scene, rng: np.random.Generator, sides: dict, ground: np.ndarray, box: BoxFn) -> None:
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
        n, c, k = box_planes(np.array([-w / 2, -h / 2, -0.015]), np.array([w / 2, h / 2, 0.015]))
        rot = yaw_matrix(yaw)
        args = [
            dict(material=SIGN, origin=centre, colour=(0, 0, 0), params=(kind, w, h, u(0.6, 1.6)))
            if nl[2] < -0.5
            else dict(material=METAL, origin=centre, colour=grey)
            for nl in n
        ]
        n, c, k = place(n, c, k, rot, centre)
        ids = scene.add_polytope(n, c, k, args)
        front = ids[4]  # the -z face of the local plate looks at the camera (before the yaw)
        scene.rois.append(Roi("sign", np.array([front]), k[[0, 2, 4, 6]]))
